"""Whether this CPU has 8-bit dot-product instructions, which INT8 inference needs to be
faster than FP32 (docs/pose.md: on an AVX2-only CPU the INT8 pose model ran no faster
than FP32 and found far people less well)."""

from __future__ import annotations

from pathlib import Path

# /proc/cpuinfo flags of 8-bit dot products: x86 VNNI (AVX-512 or AVX), AMX; Arm's
# `asimddp` (SDOT/UDOT).
INT8_DOT_PRODUCT_FLAGS = frozenset({"avx512_vnni", "avx_vnni", "amx_int8", "asimddp"})


def cpu_flags(cpuinfo: Path = Path("/proc/cpuinfo")) -> frozenset[str] | None:
    """The first processor's feature flags, or None where they cannot be read (not
    Linux)."""
    try:
        text = cpuinfo.read_text(errors="replace")
    except OSError:
        return None
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip().lower() in ("flags", "features"):
            return frozenset(value.split())
    return None


def has_int8_dot_product(flags: frozenset[str] | None) -> bool | None:
    """True or False from the flags; None when they are unknown."""
    if flags is None:
        return None
    return bool(flags & INT8_DOT_PRODUCT_FLAGS)
