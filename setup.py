"""Builds the one compiled module (the resonator walk and the decoder's score); everything
else is in pyproject.toml."""

from Cython.Build import cythonize
from setuptools import Extension, setup

setup(
    ext_modules=cythonize(
        [
            Extension(
                "rgtbus.signal._walk",
                ["rgtbus/signal/_walk.pyx"],
                # every product and sum rounded as written: no fused multiply-add
                extra_compile_args=["-O2", "-ffp-contract=off"],
            )
        ],
        compiler_directives={"language_level": 3},
    )
)
