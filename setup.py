"""Compiled parts of shapeidx; everything else is in pyproject.toml.

Each extension has a pure-Python twin that runs where it is missing (see its module).
"""

from setuptools import Extension, setup

# -ffp-contract=off: no fused multiply-adds, so the compiled pair pass rounds exactly as numpy does.
setup(
    ext_modules=[
        Extension("shapeidx.signing._pairs", ["shapeidx/signing/_pairs.c"],
                  extra_compile_args=["-O2", "-ffp-contract=off"], libraries=["dl"]),
    ]
)
