#!/usr/bin/env bash
# GPU figures for docs/pose.md: the whole stack on onnxruntime's CUDA provider beside its
# CPU provider on the same machine in one run, the TensorRT request's outcome, the INT8
# model on CUDA, and the GPU path's host side on two CPU cores (a laptop's or a
# Jetson's share), and the robot scene with five people on those two cores.
#
# Needs onnxruntime-gpu with its CUDA libraries, the models (FOLLOW_MODEL_DIR) and the
# PETS 2009 data (FOLLOW_DATA_DIR); the INT8 cell runs the model INT8_MODEL names, else
# the one `follow models prepare` made (run it once first).
# Usage: tools/bench_gpu.sh [REPEATS] [OUT_DIR]   (default 2 runs per cell, ./bench_gpu)
set -euo pipefail
repeats=${1:-2}
out=${2:-bench_gpu}
python=${PYTHON:-python3}
mkdir -p "$out"
follow() { "$python" -m follow.cli "$@"; }

echo "== machine"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader || echo "no nvidia-smi"
echo "cpu cores: $(nproc)"
"$python" -c 'import onnxruntime as o; print("onnxruntime", o.__version__, o.get_available_providers())'

echo "== provider 'tensorrt' (falls back to CUDA where TensorRT's libraries are missing)"
"$python" - <<'EOF' 2>&1 | tail -3
import logging
from follow.config import PoseConfig
from follow.pose.detector import PoseDetector
logging.basicConfig(level=logging.WARNING)
print("ran on", PoseDetector(PoseConfig(provider="tensorrt"), frame_size=(768, 576)).backend_name)
EOF

echo "== robot and PETS settings x cpu, cuda: medians of $repeats runs, camera 30 fps"
follow bench --matrix --providers cpu,cuda --repeats "$repeats" 2>"$out/matrix.stderr" \
    | tee "$out/matrix.txt"

echo "== re-id embeddings of the robot-camera crops, CUDA against CPU"
"$python" - <<'EOF' 2>&1 | tail -2
import os, pathlib, cv2, numpy as np
from follow.identify.reid import ReidEmbedder
from follow.models import resolve
crops = [cv2.imread(str(p)) for p in sorted(pathlib.Path(os.environ["FOLLOW_DATA_DIR"], "ccf_crops").glob("*.jpg"))]
model = resolve("person-reidentification-retail-0248")
gpu, cpu = ReidEmbedder(model, provider="cuda"), ReidEmbedder(model, provider="cpu")
cos = np.sum(gpu.embed_crops(crops) * cpu.embed_crops(crops), axis=1)
print(f"{len(crops)} crops on {gpu.backend_name}: cosine to the CPU's min {cos.min():.6f}")
EOF

echo "== robot settings, cuda, two CPU cores (taskset -c 0,1): re-id on the GPU, then the CPU"
printf '[identify]\nreid_provider = "cuda"\n' >"$out/reid_cuda.toml"
taskset -c 0,1 "$python" -m follow.cli bench --provider cuda --config "$out/reid_cuda.toml" \
    --json 2>"$out/two_cores_reid_cuda.stderr" | tail -1 | tee "$out/two_cores_reid_cuda.json"
taskset -c 0,1 "$python" -m follow.cli bench --provider cuda --json 2>"$out/two_cores.stderr" \
    | tail -1 | tee "$out/two_cores.json"

echo "== robot settings, cuda, the INT8 model"
if [ -n "${INT8_MODEL:-}" ]; then
    printf '[pose]\nmodel_file = "%s"\n' "$INT8_MODEL" >"$out/int8.toml"
else
    printf '[pose]\nprecision = "int8"\n' >"$out/int8.toml"
fi
follow bench --provider cuda --config "$out/int8.toml" --json 2>"$out/int8.stderr" \
    | tail -1 | tee "$out/int8.json"

echo "== robot scene (640x480, 5 people 3-8 m), cuda, two CPU cores: the robot goal's case"
taskset -c 0,1 "$python" -m follow.cli bench --provider cuda --scene robot --people 5 --far-m 8 \
    --json 2>"$out/robot5_two_cores.stderr" | tail -1 | tee "$out/robot5_two_cores.json"
taskset -c 0,1 "$python" -m follow.cli bench --provider cpu --scene robot --people 5 --far-m 8 \
    --json 2>"$out/robot5_two_cores_cpu.stderr" | tail -1 | tee "$out/robot5_two_cores_cpu.json"
