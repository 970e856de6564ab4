"""Compiled parts of shapeidx; everything else is in pyproject.toml.

Each extension has a pure-Python twin that gives the same results and runs where the
extension could not be built (no C compiler): ``optional=True`` lets the install go on.
tests/test_compiled_pairs.py and tests/test_vrml_fast.py fail where one is missing, so
that a slow install is noticed.
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        # the signature's pair pass; -ffp-contract=off: no fused multiply-adds, so it
        # rounds exactly as numpy does
        Extension("shapeidx.signing._pairs", ["shapeidx/signing/_pairs.c"],
                  extra_compile_args=["-O2", "-ffp-contract=off"], libraries=["dl"], optional=True),
        # the VRML fast path (shapeidx/io/vrml/fast.py); anything it does not know goes to
        # the Python reader
        Extension("shapeidx.io.vrml._scan", ["shapeidx/io/vrml/_scan.c"], extra_compile_args=["-O2"], optional=True),
    ]
)
