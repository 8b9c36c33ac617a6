"""The `--backend jax` feature programs kept between runs: traced once, read back after.

Tracing and lowering one bucket's features program (thousands of operations, the exact-mode rewrite)
costs 3-4 s on a CPU, every run, for every bucket and batch size: most of a warm `--backend jax` run
of a few hundred scenes. A traced program is kept as a `jax.export.Exported` (JAX's serialized
StableHLO), one file per program under the user's cache folder, and a later process calls it back
(`Exported.call`: the same operations, so the same results, bit for bit). What XLA compiles from it
is JAX's to keep (its persistent compilation cache, which the CLI turns on: `keep_compiled_programs`).

A file is found by a digest of

- the program: its name, the static facts it was traced for (the feature layout, the registered
  features by kernel), and the shapes and dtypes of its arguments;
- the code that traced it: the source of every module of this package, and the versions of JAX,
  jaxlib and numpy, so that a changed kernel never reads an old program;
- where it runs: JAX's platform (cpu, cuda, rocm).

Only programs of this package's own kernels are kept: a feature registered from elsewhere could change
without changing the digest, so its programs are traced every run, as before.

The cache never stands in the way: an entry that cannot be read or written is traced anew (one
warning). `WOSAC_JAX_PROGRAM_CACHE=off` turns it off; a path puts it there. The least recently used
files go past `MAX_BYTES`.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.metadata
import importlib.util
import os
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from wosac_eval.runtime.cache_dirs import bounded, configured_cache, user_cache_dir

ENV = "WOSAC_JAX_PROGRAM_CACHE"
MAX_BYTES = 512 << 20  # a program is 0.1-1 MB: thousands of buckets
SUFFIX = ".jaxexport"
PACKAGE = "wosac_eval"

# Programs this process traced or read back, by digest: the jitted caller of each.
_programs: dict[str, Callable] = {}
stats = {"read": 0, "written": 0}  # files read back and written by this process


def cache_dir() -> Path | None:
    """Where the programs live (`$WOSAC_JAX_PROGRAM_CACHE`, else the user's cache folder); None when off."""
    return configured_cache(ENV, "jax-programs")


@functools.cache
def code_version() -> str:
    """A digest of this package's sources as installed (every `.py` file, read as bytes) and of the
    versions of what traces and lowers its programs."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for name in ("jax", "jaxlib", "numpy"):
        digest.update(f"{name}={importlib.metadata.version(name)};".encode())
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def is_ours(function: Callable) -> bool:
    """True when `function` is defined in this package (so `code_version` covers it)."""
    module = getattr(function, "__module__", None) or ""
    return module == PACKAGE or module.startswith(PACKAGE + ".")


def program_digest(name: str, static: str, args: Any) -> str:
    """The file name of program `name` traced for `static` (a stable text of its static facts) and the
    shapes and dtypes of `args` (a pytree of arrays), by this code on this platform, with the JAX settings
    that change what a trace gives (x64, the default matmul precision)."""
    leaves, tree = jax.tree_util.tree_flatten(args)
    shapes = ";".join(f"{np.shape(a)}:{np.result_type(a)}" for a in leaves)
    settings = ",".join(
        f"{setting}={getattr(jax.config, setting, None)}"
        for setting in ("jax_enable_x64", "jax_default_matmul_precision")
    )
    text = "\n".join((code_version(), jax.default_backend(), settings, name, static, str(tree), shapes))
    return hashlib.sha256(text.encode()).hexdigest()


def kept(name: str, static: str, jitted: jax.stages.Wrapped, args: Any) -> Callable:
    """A callable that computes `jitted(*args)` (and on arguments of the same shapes): read back from the
    cache when this program was kept, else traced by exporting `jitted` and kept. With the cache off,
    `jitted` itself. Call it in the JAX context `jitted` is meant for (x64 on or off) and with `args`."""
    folder = cache_dir()
    if folder is None or not _serializer():
        return jitted
    digest = program_digest(name, static, args)
    program = _programs.get(digest)
    if program is None:
        exported = _read(folder / (digest + SUFFIX))
        if exported is None:
            exported = jax.export.export(jitted)(*args)
            _write(folder, digest + SUFFIX, exported)
        program = _programs[digest] = jax.jit(exported.call)
    return program


@functools.cache
def _serializer() -> bool:
    """True when JAX can serialize programs (it needs `flatbuffers`, in `wosac-eval[jax]`); else warns once."""
    if importlib.util.find_spec("flatbuffers") is not None:
        return True
    warnings.warn(
        f"the JAX program cache is off: JAX's serializer needs `flatbuffers` (pip install 'wosac-eval[jax]'); "
        f"programs are traced every run (set {ENV}=off to silence this)",
        RuntimeWarning,
        stacklevel=4,
    )
    return False


def _read(path: Path) -> Any:
    """The program kept at `path`, or None when absent or unreadable (warned, then traced anew)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as error:
        _warn(path, error)
        return None
    try:
        exported = jax.export.deserialize(bytearray(data))
    except Exception as error:  # noqa: BLE001 - a damaged file (struct.error and others): traced anew
        _warn(path, error)
        return None
    stats["read"] += 1
    with contextlib.suppress(OSError):
        os.utime(path)  # recently used: the last to go past MAX_BYTES
    return exported


def _write(folder: Path, name: str, exported: Any) -> None:
    """Keeps `exported` as `folder/name`, whole or not at all (a temporary file renamed), then drops the
    least recently used files past `MAX_BYTES`."""
    try:
        data = exported.serialize()
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".writing-", delete=False) as out:
            out.write(data)
        os.replace(out.name, folder / name)
    except OSError as error:
        _warn(folder / name, error)
        return
    stats["written"] += 1
    _prune(folder)


def _prune(folder: Path) -> None:
    try:
        files = [(p.stat(), p) for p in folder.glob("*" + SUFFIX)]
    except OSError:
        return
    total = sum(stat.st_size for stat, _ in files)
    for stat, path in sorted(files, key=lambda f: f[0].st_mtime):
        if total <= MAX_BYTES:
            break
        path.unlink(missing_ok=True)
        total -= stat.st_size


_warned: set[Path] = set()


def _warn(path: Path, error: Exception) -> None:
    if path in _warned:
        return
    _warned.add(path)
    warnings.warn(
        f"the JAX program cache entry {path} cannot be used ({type(error).__name__}: {error}); the program "
        f"is traced anew (set {ENV}=off to turn the cache off)",
        RuntimeWarning,
        stacklevel=4,
    )


COMPILED_MAX_BYTES = 2 << 30


def keep_compiled_programs() -> None:
    """Turns on JAX's persistent compilation cache in the user's cache folder (`jax-compiled`), unless
    JAX_COMPILATION_CACHE_DIR or the program already chose one: a program's own choice for its process
    (the CLI's), before its first compilation. The folder is emptied when it holds more than
    `COMPILED_MAX_BYTES` (`bounded`)."""
    if os.environ.get("JAX_COMPILATION_CACHE_DIR") or getattr(jax.config, "jax_compilation_cache_dir", None):
        return
    folder = user_cache_dir("jax-compiled")
    bounded(folder, COMPILED_MAX_BYTES)
    jax.config.update("jax_compilation_cache_dir", str(folder))
