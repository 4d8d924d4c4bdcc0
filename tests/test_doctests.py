"""Every module's docstring examples, imported under the one import root (``adfusion.…``).

pytest's ``--doctest-modules`` would import the repository's folders as top-level packages
(``starid.solver``), a second copy beside ``adfusion.starid.solver``; walking the installed
package runs each example exactly where a user's ``import`` finds it.
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import adfusion

# Optional extras: a module whose own dependency is not installed is skipped, and says so.
OPTIONAL = {"Basilisk": "bsk", "tetra3rs": "bench", "dask": "dist"}


def _modules() -> list[str]:
    names = ["adfusion"]
    for info in pkgutil.walk_packages(adfusion.__path__, "adfusion."):
        if info.name.endswith("__main__"):
            continue
        names.append(info.name)
    for sub in ("starid", "sensors", "logs"):
        pkg = importlib.import_module(f"adfusion.{sub}")
        names += [i.name for i in pkgutil.walk_packages(pkg.__path__, f"adfusion.{sub}.")]
    return sorted(set(names))


@pytest.mark.parametrize("name", _modules())
def test_docstring_examples(name: str) -> None:
    try:
        module = importlib.import_module(name)
    except ModuleNotFoundError as e:
        if e.name and e.name.split(".")[0] in OPTIONAL:
            pytest.skip(f"{name} needs the optional extra "
                        f"'{OPTIONAL[e.name.split('.')[0]]}' ({e.name} is not installed)")
        raise
    finder = doctest.DocTestFinder()
    tests = [t for t in finder.find(module, name) if t.examples]
    if not tests:
        pytest.skip("no examples")
    runner = doctest.DocTestRunner(optionflags=0)
    for t in tests:
        runner.run(t)
    res = runner.summarize(verbose=False)
    assert res.failed == 0, f"{res.failed} of {res.attempted} examples failed in {name}"
