"""How the package compiles its programs: `filter_jit` and `jit` are Equinox's and JAX's, with XLA's classic CPU
emitters (`xla_cpu_use_fusion_emitters` off), which compile this package's programs 1.4-1.8x faster at the same
run time (`beamdrop bench --latency`). A compile option of each program, not a global setting: the rest of the
user's JAX is untouched, the option follows the programs through `grad` and `vmap`, and a user's own `jit` around
them compiles with the user's options. Programs that ask for it (`filter_jit(dot_fusions_only=True)`) also use
YNNPACK's library fusions for matrix products only. Within `quick_programs` (the CLI's commands that run for
milliseconds) programs compile for latency instead: smaller and without LLVM's optimisation passes. An `XLA_FLAGS`
that sets an option wins; a jaxlib that does not know an option compiles as usual.

`keep_programs(folder)` (the CLI's cache) keeps each compiled program as a serialised executable, so a later process
with the same package, libraries, machine, arguments' structure and shapes loads it without tracing, lowering or
compiling. `preload_programs` starts loading named kept programs in a background thread (loading runs outside
Python's lock, so it overlaps the caller's imports). `prune_folder` bounds such a folder's size."""

import contextlib
import functools
import hashlib
import importlib.machinery
import importlib.metadata
import importlib.util
import inspect
import os
import pickle
import platform
import sys
import threading
from concurrent.futures import Future
from pathlib import Path

import jax
import numpy as np
from jax.experimental import serialize_executable

_CLASSIC_EMITTERS = "xla_cpu_use_fusion_emitters"
# YNNPACK library fusions for matrix products only (by default its reductions too), for the programs that ask:
# its reductions over a Monte-Carlo chunk's search grids took 60 % of a clattering drop (54 -> 36 us per drop).
# Not for every program: the plates' searches then round differently, which moved the placement optimiser on a
# plate and mirror-image ties of the plate tables in the test suite's compile mode.
_DOT_FUSIONS_ONLY = {"xla_cpu_experimental_ynn_fusion_type": "LIBRARY_FUSION_TYPE_DOT"}
# Programs compiled for latency (`quick_programs`): LLVM without its optimisation passes.
_QUICK = {"xla_backend_optimization_level": 0}
_quick = [False]  # a stack: the innermost `quick_programs` block decides


def _wanted(dot_fusions_only: bool, quick: bool = False) -> dict:
    return {_CLASSIC_EMITTERS: False, **(_DOT_FUSIONS_ONLY if dot_fusions_only else {}), **(_QUICK if quick else {})}


@contextlib.contextmanager
def quick_programs(on: bool = True):
    """Within the block (with `on`), the package's programs called at the top level compile for latency: LLVM
    without its optimisation passes, and `_trig.sincos` as XLA's own sine and cosine (a smaller program). The
    default drop's program compiles in 0.35 s instead of 0.8 s and runs in 3 ms instead of 1.6 ms (2-core
    development machine): for one-off calls whose run takes milliseconds, such as the CLI's single drop; never
    for Monte-Carlo chunks or optimisers, whose runs outweigh their compiles."""
    _quick.append(bool(on))
    try:
        yield
    finally:
        _quick.pop()


def is_quick() -> bool:
    """Whether programs traced now compile for latency (`quick_programs`)."""
    return _quick[-1]


def _requested(dot_fusions_only: bool, quick: bool) -> dict:
    """`_wanted` less the options that `XLA_FLAGS` sets."""
    return {k: v for k, v in _wanted(dot_fusions_only, quick).items() if k not in os.environ.get("XLA_FLAGS", "")}


@functools.cache
def compiler_options(dot_fusions_only: bool = False, quick: bool = False) -> dict | None:
    """The package's compile options: `{"xla_cpu_use_fusion_emitters": False}`, with `dot_fusions_only` also
    `_DOT_FUSIONS_ONLY`, with `quick` also `_QUICK`; less those that `XLA_FLAGS` sets or that jaxlib does not know
    (checked once, by compiling a one-operation program with them, then with each where that fails). None if none
    is left."""

    def known(options):
        try:
            jax.jit(lambda x: x + 1, compiler_options=options).lower(0).compile()
        except jax.errors.JaxRuntimeError:  # "No such compile option"
            return False
        return True

    options = _requested(dot_fusions_only, quick)
    if options and not known(options):
        options = {k: v for k, v in options.items() if known({k: v})}
    return options or None


_folders: list[tuple[Path, list[str]]] = []  # the folder of `keep_programs` and the programs used, while active
_preloaded: dict[Path, Future] = {}  # kept programs being loaded by `preload_programs`


@contextlib.contextmanager
def keep_programs(folder):
    """Within the block, the package's programs called at the top level are kept in `folder` as compiled
    executables and loaded from there when a call matches one: same function, package source, library versions,
    machine, precision, compile options, static arguments, and arrays' shapes and dtypes. Only module-level
    `filter_jit` functions whose static arguments print without object addresses are kept (a closure's name does
    not say what it captured). Yields a list that collects the file names of the programs used (loaded or kept),
    for `preload_programs` in a later process."""
    used = []
    _folders.append((Path(folder), used))
    try:
        yield used
    finally:
        _folders.pop()


@functools.cache
def _initialise_lapack() -> None:
    """Point jaxlib's LAPACK kernels at their routines, as lowering `eigh` or `solve` does in a process that
    compiles: a kept program that calls them (every plate program: `eigh`) loads without lowering, and without
    this its first call jumps to an unset routine (a segmentation fault). Called before a kept program that needs
    it runs, on the caller's thread (under Python's lock), which a program without LAPACK calls (a beam's) never
    needs."""
    try:
        from jaxlib import lapack

        with _scipy_lapack_alone():
            lapack._lapack.initialize()
    except (ImportError, AttributeError):  # another jaxlib layout: lower a small `eigh`, which initialises it
        import jax.numpy as jnp

        jax.jit(jnp.linalg.eigh).lower(np.eye(2))


@contextlib.contextmanager
def _scipy_lapack_alone():
    """SciPy's `scipy.linalg.cython_blas` and `cython_lapack` in `sys.modules` without the `scipy.linalg` package,
    for jaxlib's LAPACK set-up, which imports them: the package imports much of SciPy (0.24 s, a sixth of a warm
    plate drop, against 0.03 s for the two). Taken out of `sys.modules` afterwards, so that a later
    `import scipy.linalg` runs as usual; it gets the same two modules (Cython keeps one module object per process).
    Where SciPy is laid out otherwise, or `scipy.linalg` is imported already, the set-up imports as it does."""
    added = []
    try:
        if "scipy.linalg" not in sys.modules:
            where = importlib.util.find_spec("scipy.linalg").submodule_search_locations
            for name in ("scipy.linalg.cython_blas", "scipy.linalg.cython_lapack"):
                if name not in sys.modules:
                    spec = importlib.machinery.PathFinder.find_spec(name, where)
                    module = importlib.util.module_from_spec(spec)
                    sys.modules[name] = module
                    added.append(name)
                    spec.loader.exec_module(module)
    except Exception:  # noqa: BLE001 - a SciPy laid out otherwise: the set-up imports the package itself
        for name in added:
            sys.modules.pop(name, None)
        added = []
    try:
        yield
    finally:
        for name in added:
            sys.modules.pop(name, None)


def _deserialise(data: bytes):
    """A kept program's file contents -> (executable, pickled output template, whether it calls LAPACK)."""
    return _load(pickle.loads(data))


def _load(parts):
    payload, in_tree, out_tree, template, lapack = parts
    return serialize_executable.deserialize_and_load(payload, in_tree, out_tree), template, lapack


def preload_programs(folder, names) -> threading.Thread:
    """Start loading the kept programs `names` (file names in `folder`, as collected by `keep_programs`) in a
    background thread; a call that needs one of them then waits for it instead of loading it itself. A hint only:
    a program absent, unreadable or never called costs its loading and nothing else. Where one calls LAPACK, its
    routines are set up here, on the caller's thread, while the thread loads. Returns the thread."""
    jobs = []
    for name in names:
        if isinstance(name, str) and "/" not in name:
            path, future = Path(folder) / name, Future()
            _preloaded[path] = future
            try:  # read and unpickled here (milliseconds); loaded by the thread
                jobs.append((pickle.loads(path.read_bytes()), future))
            except Exception as error:  # noqa: BLE001 - the call loads or compiles it itself and says why
                future.set_exception(error)

    def load_one(parts, future):
        try:
            future.set_result(_load(parts))
        except Exception as error:  # noqa: BLE001 - as above
            future.set_exception(error)

    def load():
        # One thread per program: XLA loads without Python's lock, and a plate's drop waits for its modes' program
        # and its drop's (60 ms and 390 ms to load on 2 cores) together instead of one after the other.
        loaders = [threading.Thread(target=load_one, args=job, daemon=True) for job in jobs]
        for loader in loaders:
            loader.start()
        for loader in loaders:
            loader.join()

    thread = threading.Thread(target=load, name="beamdrop-preload", daemon=True)
    thread.start()
    if any(parts[-1] is True for parts, _ in jobs):
        _initialise_lapack()
    return thread


def prune_folder(folder, max_bytes: int, keep=lambda path: False) -> int:
    """Delete the least recently used files under `folder` (by modification time; a kept program is touched when
    loaded) until the rest fit in `max_bytes`; files that `keep` accepts stay. Returns the bytes freed. A file
    another process removes first, or one that cannot be removed, is skipped."""
    files = []
    for path in Path(folder).rglob("*"):
        try:
            if path.is_file() and not keep(path):
                stat = path.stat()
                files.append((stat.st_mtime, stat.st_size, path))
        except OSError:
            continue
    total, freed = sum(size for _, size, _ in files), 0
    for _, size, path in sorted(files, key=lambda f: f[0]):
        if total - freed <= max_bytes:
            break
        try:
            path.unlink()
            freed += size
        except OSError:
            continue
    return freed


@functools.cache
def _environment() -> str:
    """What a kept program depends on besides its arguments: this package's source, the libraries it traces and
    compiles with, and the processor it was compiled for (an executable uses the host's instruction set)."""
    digest = hashlib.sha256()
    package = Path(__file__).parents[1]
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode() + path.read_bytes())
    versions = []
    for name in ("jax", "jaxlib", "equinox", "diffrax", "lineax", "optimistix", "jaxtyping", "numpy"):
        try:
            versions.append(f"{name}={importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            versions.append(f"{name}=none")
    try:
        cpu = next((line for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags")), "")
    except OSError:
        cpu = platform.processor()
    machine = hashlib.sha256(f"{platform.machine()};{cpu}".encode()).hexdigest()
    return ";".join([digest.hexdigest(), *versions, jax.default_backend(), machine])


@functools.cache
def _hit_counter() -> list[int]:
    hits = [0]

    def count(event: str, **kwargs):
        if event == "/jax/compilation_cache/cache_hits":
            hits[0] += 1

    jax.monitoring.register_event_listener(count)
    return hits


def _cache_hits() -> int:
    """Programs loaded from JAX's persistent compilation cache in this process so far."""
    return _hit_counter()[0]


class _Slot(int):
    """Where the i-th array output goes in a kept program's output template."""


class _Compiled:
    """A function compiled with `compiler_options()` where it is called on its own, and as usual where it is traced
    into another program (`grad`, `vmap`, an enclosing `jit`): JAX takes compile options on top-level programs only
    (and says so with a ValueError while tracing, before anything is staged, where no argument shows it)."""

    def __init__(self, make, fun, jit_kwargs, dot_fusions_only=False):
        self._make, self._fun, self._jit_kwargs = make, fun, jit_kwargs
        self._dot_fusions_only = dot_fusions_only
        self._programs = {}  # (quick, called on its own) -> program, made on the first such call
        self._quick_fun = None
        self._loaded = {}  # key -> (executable on the array leaves, output template)
        # `jax.jit` traces Python numbers, which a kept program would fix as constants: Equinox's programs only.
        self._keepable = make is _filter_jit() and inspect.isfunction(fun) and "<" not in fun.__qualname__
        self._name = f"{getattr(fun, '__module__', '')}.{getattr(fun, '__qualname__', '')}"
        functools.update_wrapper(self, fun)

    def __call__(self, *args, **kwargs):
        quick = is_quick()
        # Traced arguments (grad, vmap, an enclosing jit) stage the program into another: no options there.
        if not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves((args, kwargs))):
            try:
                if _folders and self._keepable:
                    out = self._call_kept(*_folders[-1], args, kwargs)
                    if out is not None:
                        return out
                return self._program(quick, True)(*args, **kwargs)
            except ValueError as error:
                if "compiler_options" not in str(error):
                    raise
        return self._program(quick, False)(*args, **kwargs)

    def _program(self, quick: bool, on_its_own: bool):
        """The jitted function for a call in or out of `quick_programs`, on its own (with the compile options) or
        traced into another program. Quick programs jit a twin of the function: JAX caches traces by function, and
        a quick trace (XLA's sine) must not be reused outside the block, nor the usual one inside."""
        key = (quick, on_its_own)
        if key not in self._programs:
            options = compiler_options(self._dot_fusions_only, quick) if on_its_own else None
            if on_its_own and options is None:
                self._programs[key] = self._program(quick, False)
            else:
                if quick and self._quick_fun is None:
                    self._quick_fun = functools.wraps(self._fun)(lambda *a, **k: self._fun(*a, **k))
                fun = self._quick_fun if quick else self._fun
                extra = {} if options is None else {"compiler_options": options}
                self._programs[key] = self._make(fun, **self._jit_kwargs, **extra)
        return self._programs[key]

    def _call_kept(self, folder: Path, used: list[str], args, kwargs):
        """The call through a kept program (loaded, or compiled and kept now); None where it cannot be kept."""
        import equinox as eqx

        arrays, static = eqx.partition((args, kwargs), eqx.is_array)
        leaves, treedef = jax.tree_util.tree_flatten(arrays)
        shapes = [(x.shape, str(x.dtype), bool(getattr(x, "weak_type", False))) for x in leaves]
        # The options as asked for and XLA_FLAGS, not as probed: with jaxlib's version (in the environment) they
        # decide the probe's answer, and a loaded program then needs no probe (a compile, 15 ms).
        try:  # the static parts as their structure and plain leaves (a module's own repr may need its arrays)
            text = repr((self._name, treedef, jax.tree_util.tree_flatten(static),
                         shapes, jax.config.jax_enable_x64, _wanted(self._dot_fusions_only, is_quick()),
                         os.environ.get("XLA_FLAGS", ""), _environment()))
        except Exception:  # noqa: BLE001 - what does not print is not kept
            return None
        if " at 0x" in text:
            return None
        key = hashlib.sha256(text.encode()).hexdigest()[:40]
        if key not in self._loaded:
            path = folder / f"{self._name.rsplit('.', 1)[-1]}-{key}.xla"
            preloaded = _preloaded.pop(path, None)
            try:
                compiled, template, lapack = (_deserialise(path.read_bytes()) if preloaded is None
                                              else preloaded.result())
                if lapack:
                    _initialise_lapack()
                template = pickle.loads(template)
                with contextlib.suppress(OSError):
                    os.utime(path)  # used now: `prune_folder` removes the least recently used first
            except Exception:  # noqa: BLE001 - absent, partly written or unreadable: compile it again
                compiled, template, fresh = self._compile_kept(treedef, static, leaves, key)
                if compiled is None:
                    return None
                if fresh:
                    try:
                        folder.mkdir(parents=True, exist_ok=True)
                        scratch = path.with_suffix(f".{os.getpid()}")
                        # The template pickled apart: it names the package's classes, which a preloading thread
                        # would have to import.
                        lapack = "lapack_" in compiled.as_text()  # its custom calls' targets
                        scratch.write_bytes(pickle.dumps((*serialize_executable.serialize(compiled),
                                                          pickle.dumps(template), lapack)))
                        scratch.replace(path)  # whole files only: another process may be reading
                    except Exception:  # noqa: BLE001 - an output that does not pickle, a full disk: not kept
                        pass
            self._loaded[key] = (compiled, template)
            used.append(path.name)
        call, template = self._loaded[key]
        outputs = call(*leaves)
        return jax.tree_util.tree_map(lambda v: outputs[v] if isinstance(v, _Slot) else v, template)

    def _compile_kept(self, treedef, static, leaves, key: str):
        """The program compiled over the arguments' array leaves, its output template (the output with each array
        replaced by its `_Slot`), and whether it was compiled here: an executable loaded from JAX's compilation
        cache does not serialise whole again (its calls fail with "Function ... not found"), so only programs
        compiled here are kept; the program also returns its key, so that JAX's cache holds it only where it was
        compiled here (a new package source with the same program is compiled and kept anew). (None, None,
        False) where it does not compile so (the usual call says why)."""
        import equinox as eqx

        box = []

        def on_arrays(*arrays):
            args, kwargs = eqx.combine(jax.tree_util.tree_unflatten(treedef, arrays), static)
            out_leaves, out_tree = jax.tree_util.tree_flatten(self._fun(*args, **kwargs))
            slots = iter(range(len(out_leaves)))
            box.append(jax.tree_util.tree_unflatten(
                out_tree, [_Slot(next(slots)) if eqx.is_array(v) else v for v in out_leaves]))
            return [v for v in out_leaves if eqx.is_array(v)] + [np.uint32(int(key[:8], 16))]

        quick = is_quick()
        hits = _cache_hits()
        try:
            lowered = jax.jit(on_arrays).lower(*leaves)
            try:  # the options as asked for: a probe (`compiler_options`, a compile) only where jaxlib refuses one
                compiled = lowered.compile(_requested(self._dot_fusions_only, quick) or None)
            except jax.errors.JaxRuntimeError as error:
                if "compile option" not in str(error):
                    raise
                compiled = lowered.compile(compiler_options(self._dot_fusions_only, quick))
        except Exception:  # noqa: BLE001 - the usual call raises it again, from the package's own program
            return None, None, False
        return compiled, box[0], _cache_hits() == hits


def filter_jit(fun=None, *, dot_fusions_only: bool = False, **jit_kwargs):
    """`eqx.filter_jit`, compiled with `compiler_options(dot_fusions_only)` at the top level."""
    if fun is None:
        return functools.partial(filter_jit, dot_fusions_only=dot_fusions_only, **jit_kwargs)
    return _Compiled(_filter_jit(), fun, jit_kwargs, dot_fusions_only)


def _filter_jit():
    # Equinox is imported where first needed, not with this module: the CLI imports this module first to start
    # `preload_programs` while Equinox and the package import.
    import equinox as eqx

    return eqx.filter_jit


def jit(fun=None, **jit_kwargs):
    """`jax.jit`, compiled with `compiler_options()` at the top level."""
    if fun is None:
        return functools.partial(jit, **jit_kwargs)
    return _Compiled(jax.jit, fun, jit_kwargs)
