"""Rewrite the wheel builder's Python paths baked into the ROS 2 wheels' CMake files.

The PyPI ROS 2 Jazzy wheels were built under /opt/python/cp311-cp311; their exported CMake
targets name that interpreter's include directory and NumPy's include directory, which do
not exist here, so `colcon build` of an interface package fails with "Imported target ...
includes non-existent path". This replaces both with the venv interpreter's paths.

Usage: python fix_cmake_paths.py VENV
Idempotent: files already fixed are left alone.
"""
from __future__ import annotations

import sys
import sysconfig
from pathlib import Path

import numpy

BUILDER_INCLUDE = "/opt/python/cp311-cp311/include/python3.11"
BUILDER_NUMPY = "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    share = Path(argv[1]) / "share"
    include = sysconfig.get_paths()["include"]
    numpy_include = numpy.get_include()
    changed = 0
    for path in share.rglob("*.cmake"):
        text = path.read_text(encoding="utf-8", errors="surrogateescape")
        if BUILDER_INCLUDE not in text and BUILDER_NUMPY not in text:
            continue
        # NumPy first: the builder's include path is not a prefix of it, but be explicit.
        text = text.replace(BUILDER_NUMPY, numpy_include).replace(BUILDER_INCLUDE, include)
        path.write_text(text, encoding="utf-8", errors="surrogateescape")
        changed += 1
    print(f"[setup] CMake path fix: {changed} file(s) rewritten under {share}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
