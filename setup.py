"""Build configuration beyond pyproject.toml: the optional C extension ``protocol._speedups``.

Everything else (metadata, dependencies, packages) is in pyproject.toml. The extension is COBS and
CRC-16 in C for the frame codec (protocol/speedups.py); ``optional=True`` lets a machine without a C
compiler install the package anyway, and then the codec runs on the pure-Python reference.
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "protocol._speedups",
            sources=["protocol/_speedups.c"],
            extra_compile_args=["-O2"],
            optional=True,
        )
    ]
)
