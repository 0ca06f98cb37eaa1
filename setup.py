"""The package's one compiled part: the quality checks' and the Allan analysis' passes over a
raw log (hse_opt/align/_kernels.c). Optional: where no C compiler is present the build goes on without
it and hse_opt.align takes numpy's route (hse_opt/align/_compiled.py: the same figures to
rounding, slower)."""
import os

from setuptools import Extension, setup

setup(ext_modules=[Extension("hse_opt.align._kernels", ["hse_opt/align/_kernels.c"], optional=True,
                             # (no fused multiply-add: the kernels take numpy's route's roundings)
                             extra_compile_args=[] if os.name == "nt" else ["-O3", "-ffp-contract=off"])])
