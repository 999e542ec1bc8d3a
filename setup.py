"""Builds the one compiled module (the resonator walk and the decoder's score) and maps the
repository's top-level ``units/`` and ``scenarios/`` into the ``rgtbus`` package (installed as
``rgtbus.units`` and ``rgtbus.scenarios``: no generic top-level ``units`` in site-packages);
everything else is in pyproject.toml."""

from Cython.Build import cythonize
from setuptools import Extension, find_packages, setup

MAPPED = {
    "rgtbus.units": "units",
    "rgtbus.scenarios": "scenarios",  # data only: the shipped scenarios, found by name
    "rgtbus.scenarios.sweeps": "scenarios/sweeps",
}

setup(
    packages=[*find_packages(include=["rgtbus", "rgtbus.*"]), *MAPPED, "rgtbus.telemetry.schemas"],
    package_dir=MAPPED,
    package_data={
        "rgtbus": ["py.typed"],
        "rgtbus.telemetry.schemas": ["*.json"],
        "rgtbus.scenarios": ["*.toml"],
        "rgtbus.scenarios.sweeps": ["*.toml"],
    },
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
    ),
)
