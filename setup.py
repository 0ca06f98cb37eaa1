"""The package's one compiled part: the raw-log path's passes over a record
(hse_opt/align/_kernels.c). Optional: where no C compiler is present the build goes on without
it and hse_opt.align.blocks takes numpy's route (the same sums to rounding, slower)."""
from setuptools import Extension, setup

setup(ext_modules=[Extension("hse_opt.align._kernels", ["hse_opt/align/_kernels.c"], optional=True,
                             extra_compile_args=["-O3"] if __import__("os").name != "nt" else [])])
