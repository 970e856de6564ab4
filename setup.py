"""Compiled parts of shapeidx; everything else is in pyproject.toml.

Each extension has a pure-Python twin that gives the same results and runs where the
extension could not be built (no C compiler): ``optional=True`` lets the install go on.
tests/test_compiled_pairs.py fails where it is missing, so that a slow install is noticed.
"""

from setuptools import Extension, setup

# -ffp-contract=off: no fused multiply-adds, so the compiled pair pass rounds exactly as numpy does.
setup(
    ext_modules=[
        Extension("shapeidx.signing._pairs", ["shapeidx/signing/_pairs.c"],
                  extra_compile_args=["-O2", "-ffp-contract=off"], libraries=["dl"], optional=True),
    ]
)
