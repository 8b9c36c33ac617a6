"""The machinery of `wosac_eval.compat.official_names`: an import hook that serves the official package's names.

`import waymo_open_dataset...` resolves to wosac-eval for every official module it serves (`SERVED`: the same
module objects as `wosac_eval.compat.*` and `wosac_eval.protos.*`); the official packages on the way
(`PACKAGES`) are packages whose folder is the matching one under the root of `wosac_eval.compat`, so
`os.path.join(waymo_open_dataset.__path__[0], "wdl_limited/...")` finds the official configs where the official
package keeps them. Any other module of the official package raises `ModuleNotFoundError` naming it and saying
it is not served.

Worker processes see the same mapping: `install` sets the environment variable `WOSAC_EVAL_OFFICIAL_NAMES`,
which processes started from this one inherit (multiprocessing's spawn and forkserver workers, subprocesses),
and the installed package's `wosac_eval_official_names.pth` calls `install_from_environment` at their start
when it is set. (Fork workers inherit the hook with the memory.)

The rule when the official package is installed too: wosac-eval never shadows it. `install` raises
`OfficialPackageFound` naming where it is; with the environment variable, the program's first
`import waymo_open_dataset` raises it. A folder named `waymo_open_dataset` that holds no Python modules (such
as the official tests' data layout in a working folder) is not the official package.

Nothing here runs at import: `official_names` (the opt-in) and the .pth call `install`.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import os
import sys
import types
from collections.abc import Sequence
from pathlib import Path
from typing import Any

PACKAGE = "waymo_open_dataset"
ENVIRONMENT = "WOSAC_EVAL_OFFICIAL_NAMES"
ROOT = Path(__file__).resolve().parent  # the official package's root, as wosac_eval.compat lays it out

# The official modules served (relative to the package) -> the wosac-eval module that is imported for them.
SERVED = {
    "protos.map_pb2": "wosac_eval.protos.map_pb2",
    "protos.scenario_pb2": "wosac_eval.protos.scenario_pb2",
    "protos.sim_agents_metrics_pb2": "wosac_eval.protos.sim_agents_metrics_pb2",
    "protos.sim_agents_submission_pb2": "wosac_eval.protos.sim_agents_submission_pb2",
    "utils.trajectory_utils": "wosac_eval.compat.trajectory_utils",
    "utils.sim_agents.converters": "wosac_eval.compat.converters",
    "utils.sim_agents.submission_specs": "wosac_eval.compat.submission_specs",
    "utils.sim_agents.test_utils": "wosac_eval.compat.test_utils",
    "utils.sim_agents.visualizations": "wosac_eval.compat.visualizations",
    "wdl_limited.sim_agents_metrics.estimators": "wosac_eval.compat.estimators",
    "wdl_limited.sim_agents_metrics.interaction_features": "wosac_eval.compat.interaction_features",
    "wdl_limited.sim_agents_metrics.map_metric_features": "wosac_eval.compat.map_metric_features",
    "wdl_limited.sim_agents_metrics.metric_features": "wosac_eval.compat.metric_features",
    "wdl_limited.sim_agents_metrics.metrics": "wosac_eval.compat.metrics",
    "wdl_limited.sim_agents_metrics.traffic_light_features": "wosac_eval.compat.traffic_light_features",
    "wdl_limited.sim_agents_metrics.trajectory_features": "wosac_eval.compat.trajectory_features",
}
# The official packages on the way to them ("" is the package itself).
PACKAGES = ("", "protos", "utils", "utils.sim_agents", "wdl_limited", "wdl_limited.sim_agents_metrics")
_CODE_SUFFIXES = (".py", ".pyc", ".so", ".pyd")


class OfficialPackageFound(ImportError):
    """The official waymo_open_dataset is importable: wosac-eval will not shadow it."""


def _official_name(fullname: str) -> str | None:
    """The name relative to the official package ("" for the package), or None for another module."""
    if fullname == PACKAGE:
        return ""
    return fullname[len(PACKAGE) + 1 :] if fullname.startswith(PACKAGE + ".") else None


def not_served_message(fullname: str) -> str:
    return (
        f"No module named {fullname!r}: wosac-eval does not serve it. The official names it serves are "
        f"{PACKAGE}.{{{', '.join(sorted(SERVED))}}} (docs/official-api.md); {fullname} needs the official package "
        f"(without `import wosac_eval.compat.official_names` and {ENVIRONMENT})"
    )


class _ServedPackage(importlib.abc.Loader):
    """An official package on the way to the served modules: a package over its compat folder, nothing else."""

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> None:
        return None  # a plain module object; the import system sets its __path__ from the spec

    def exec_module(self, module: types.ModuleType) -> None:
        module.__file__ = None  # as the official package, a namespace package, has none


class _ServedModule(importlib.abc.Loader):
    """An official module served by a wosac-eval module: the import returns that very module."""

    def __init__(self, target: str) -> None:
        self.target = target

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> None:
        return None

    def exec_module(self, module: types.ModuleType) -> None:
        # The import system returns what sys.modules holds under the name once the loader is done (the
        # language reference, "Loaders": a module may replace itself there), so the official name and the
        # wosac-eval name are one module object, and the wosac-eval module's own attributes stay its own.
        sys.modules[module.__name__] = importlib.import_module(self.target)


class _OfficialNames(importlib.abc.MetaPathFinder):
    """Finds every `waymo_open_dataset` name: a served module, a package on the way, or a clear refusal."""

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: types.ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        official = _official_name(fullname)
        if official is None:
            return None
        if official in PACKAGES:
            spec = importlib.machinery.ModuleSpec(fullname, _ServedPackage(), is_package=True)
            spec.submodule_search_locations = [str(ROOT.joinpath(*official.split(".")) if official else ROOT)]
            return spec
        if official in SERVED:
            return importlib.machinery.ModuleSpec(fullname, _ServedModule(SERVED[official]))
        # Not `name=fullname`: the import system would turn the refusal of `from waymo_open_dataset.x import y`
        # into "cannot import name" and drop this message.
        raise ModuleNotFoundError(not_served_message(fullname))


class _Refusal(importlib.abc.MetaPathFinder):
    """Raises the conflict at the first `waymo_open_dataset` import (the environment's opt-in, which cannot
    raise while Python starts)."""

    def __init__(self, error: OfficialPackageFound) -> None:
        self.error = error

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: types.ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if _official_name(fullname) is not None:
            raise OfficialPackageFound(str(self.error))
        return None


def _finders() -> list:
    return [f for f in sys.meta_path if isinstance(f, (_OfficialNames, _Refusal))]


def installed() -> bool:
    """True when this process serves the official names."""
    return any(isinstance(f, _OfficialNames) for f in sys.meta_path)


def _holds_code(spec: Any) -> bool:
    """True for a module or a package with Python modules in its folder or in the official subfolders."""
    if spec.origin and spec.origin.endswith(_CODE_SUFFIXES):
        return True
    for folder in spec.submodule_search_locations or ():
        for sub in ("", "protos", "utils", "wdl_limited"):
            place = Path(folder, sub)
            if place.is_dir() and any(p.suffix in _CODE_SUFFIXES for p in place.iterdir()):
                return True
    return False


def official_package_location() -> str | None:
    """Where an official waymo_open_dataset would be imported from (by the finders other than ours), or None."""
    loaded = sys.modules.get(PACKAGE)
    if loaded is not None and not isinstance(getattr(loaded, "__loader__", None), _ServedPackage):
        return str(getattr(loaded, "__path__", [getattr(loaded, "__file__", PACKAGE)])[0])
    spec = importlib.util.find_spec(PACKAGE)
    if spec is None or not _holds_code(spec):
        return None
    if spec.origin and spec.origin != "namespace":
        return spec.origin
    return str(next(iter(spec.submodule_search_locations or [PACKAGE])))


def install() -> None:
    """Serves the official names in this process and in the processes it starts (idempotent).

    Raises:
      OfficialPackageFound: the official waymo_open_dataset is importable (naming where it is).
    """
    if installed():
        return
    found = official_package_location()
    if found is not None:
        raise OfficialPackageFound(
            f"the official {PACKAGE} is installed ({found}): wosac-eval does not shadow it. Uninstall it (pip "
            f"uninstall waymo-open-dataset-tf-2-12-0, or the package of your TensorFlow version) to run this "
            f"program on wosac-eval, or leave out `import wosac_eval.compat.official_names` and {ENVIRONMENT} "
            "to run it on the official package"
        )
    sys.meta_path.insert(0, _OfficialNames())
    os.environ[ENVIRONMENT] = "1"  # processes started from here serve them too (the .pth at their start)


def install_from_environment() -> None:
    """What `wosac_eval_official_names.pth` runs at every start where the environment variable is set: `install`,
    or, where the official package is found, the refusal at the first `waymo_open_dataset` import (a .pth
    cannot stop Python's start with a clear message)."""
    if _finders():
        return
    try:
        install()
    except OfficialPackageFound as error:
        sys.meta_path.insert(0, _Refusal(error))


def uninstall() -> None:
    """Stops serving the official names here and in processes started from now on (the served modules stay
    imported under their wosac-eval names)."""
    for finder in _finders():
        sys.meta_path.remove(finder)
    for name in [n for n in sys.modules if _official_name(n) is not None]:
        del sys.modules[name]
    os.environ.pop(ENVIRONMENT, None)
