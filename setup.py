"""Compiled parts; everything else about the package is in pyproject.toml."""

from setuptools import Extension, setup

setup(
    ext_modules=[
        # VRML fast path (shapeidx/io/vrml/fast.py falls back to Python without it)
        Extension("shapeidx.io.vrml._scan", ["shapeidx/io/vrml/_scan.c"], extra_compile_args=["-O2"]),
    ]
)
