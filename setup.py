"""Builds the one compiled module (the resonator walk and the decoder's score) and maps the
repository's top-level ``units/`` and ``scenarios/`` into the ``rgtbus`` package (installed as
``rgtbus.units`` and ``rgtbus.scenarios``: no generic top-level ``units`` in site-packages);
everything else is in pyproject.toml."""

import re
from pathlib import Path

from Cython.Build import cythonize
from setuptools import Extension, find_packages, setup

# where the repository's files are read on the web: the README's links to them are made
# absolute for a package index (on the index a relative link leads nowhere); pyproject.toml's
# [project.urls] name the same place
REPOSITORY = "https://github.com/rgtbus/rgtbus"
_RELATIVE = re.compile(r"(!?)\[([^\]]*)\]\((?!https?://|mailto:|#)([^)\s]+)\)")


def long_description() -> str:
    """README.md with every relative link absolute (images from the raw files)."""

    def absolute(m: re.Match[str]) -> str:
        bang, text, target = m.groups()
        base = f"{REPOSITORY}/raw/main/" if bang else f"{REPOSITORY}/blob/main/"
        return f"{bang}[{text}]({base}{target})"

    return _RELATIVE.sub(absolute, Path(__file__).with_name("README.md").read_text("utf-8"))


LIMITED_API = "0x030B0000"  # Python 3.11

MAPPED = {
    "rgtbus.units": "units",
    "rgtbus.scenarios": "scenarios",  # data only: the shipped scenarios, found by name
    "rgtbus.scenarios.sweeps": "scenarios/sweeps",
    "rgtbus.scenarios.studies": "scenarios/studies",  # study files and their reference curves
}

EXTENSIONS = cythonize(
    [
        Extension(
            "rgtbus.signal._walk",
            ["rgtbus/signal/_walk.pyx"],
            # every product and sum rounded as written: no fused multiply-add
            extra_compile_args=["-O2", "-ffp-contract=off"],
            # CPython's stable ABI from 3.11 on: one wheel (abi3) for every later Python
            define_macros=[("Py_LIMITED_API", LIMITED_API)],
            py_limited_api=True,
        )
    ],
    compiler_directives={"language_level": 3},
)
# Optional: with no C compiler the package installs all the same, and runs on the module's
# NumPy twin (rgtbus.signal.kernels says so once). Set on cythonize's Extensions: it makes new
# ones and drops the flag.
for _ext in EXTENSIONS:
    _ext.optional = True


setup(
    long_description=long_description(),
    long_description_content_type="text/markdown",
    packages=[*find_packages(include=["rgtbus", "rgtbus.*"]), *MAPPED, "rgtbus.telemetry.schemas"],
    package_dir=MAPPED,
    package_data={
        "rgtbus": ["py.typed"],
        "rgtbus.telemetry.schemas": ["*.json"],
        "rgtbus.scenarios": ["*.toml"],
        "rgtbus.scenarios.sweeps": ["*.toml"],
        "rgtbus.scenarios.studies": ["*.toml", "*.csv"],
    },
    ext_modules=EXTENSIONS,
    options={"bdist_wheel": {"py_limited_api": "cp311"}},
)
