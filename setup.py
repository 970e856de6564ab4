"""Compiled parts; everything else about the package is in pyproject.toml."""

from setuptools import Extension, setup

setup(
    ext_modules=[
        # VRML fast path; optional: without a C compiler the install goes on and
        # shapeidx/io/vrml/fast.py reads every file in Python
        Extension("shapeidx.io.vrml._scan", ["shapeidx/io/vrml/_scan.c"], extra_compile_args=["-O2"], optional=True),
    ]
)
