"""Run every benchmark in this folder: ``python -m benchmarks`` (or ``make bench``)."""

import importlib
import pkgutil
import sys
from pathlib import Path

here = Path(__file__).parent
names = sorted(m.name for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_"))
for name in names:
    print(f"\n== benchmarks.{name}")
    module = importlib.import_module(f"benchmarks.{name}")
    sys.argv = [f"benchmarks.{name}"]
    module.main()
