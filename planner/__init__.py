"""The planner: pure computation (numbers in, numbers out; no I/O)."""

from planner.kernel_cache import install as _install_kernel_cache

_install_kernel_cache()  # before any planner module compiles a kernel
