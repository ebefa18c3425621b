"""Skeleton detection: OpenPose network (onnxruntime) and its decoding."""
