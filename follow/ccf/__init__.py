"""Convolutional channel features for appearance."""
