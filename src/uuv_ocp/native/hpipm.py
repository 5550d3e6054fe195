"""HPIPM and BLASFEO built for this CPU: the optional fast QP of the C real-time iteration.

The CasADi wheel ships BLASFEO built for ``TARGET_GENERIC`` (plain C kernels).  HPIPM's
interior-point iterations on the RTI QP spend their time in BLASFEO, so a BLASFEO built with
its AVX2/FMA kernels (``X64_INTEL_HASWELL``) makes each iteration about twice as fast (see
docs/solvers.md for the measurement and its command).  Nothing here runs on import or in a
constructor: :func:`build` is explicit (``uuv-ocp hpipm build``, ``make hpipm``), and the C step
links the build only when :func:`installed` finds it intact.

Sources: a directory holding ``blasfeo/`` and ``hpipm/`` checkouts, or, by default, the copies
vendored in the ``rockit-meco`` source distribution on PyPI (acados' submodules, BSD-2), fetched
with ``pip download`` and checked against a pinned SHA-256.  The build goes into
``<cache>/hpipm/<key>/`` (key: 16 hex digits of the digest of the sources, the target and the
compiler) with a manifest of SHA-256 digests of every library and header;
``<cache>/hpipm/native.json`` names the build in use.  Both static libraries are linked into the
step's shared library with their symbols hidden, so they never meet the wheel's ``libhpipm``
that CasADi itself loads.

Its headers are compiled and its libraries linked into code this process loads, so a build is
used only after :func:`installed` has checked all of it: the cache, ``hpipm/`` and every folder
of the build are folders of the current user that others cannot write (symbolic links are
refused), ``native.json`` is such a file and names a key of 16 hex digits (never a path), the
build holds exactly the files of its manifest, each one such a file with the recorded SHA-256.
Everything :func:`build` writes gets mode ``0600`` (folders ``0700``), whatever the umask.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from uuv_ocp.native.compile import (
    FILE_MODE,
    FOLDER_MODE,
    BuildDirectoryError,
    IntegrityError,
    _write_private,
    check_private_file,
    default_cache_directory,
    find_c_compiler,
    read_private_file,
    secure_directory,
)

#: the source distribution whose vendored BLASFEO and HPIPM are built by default
SDIST_NAME, SDIST_VERSION = "rockit-meco", "0.2.8"
SDIST_SHA256 = "722725589402c3761f302e39901507ae2d1ff9af95966774ed0709680f4dfa07"
#: where BLASFEO and HPIPM sit inside that source distribution
SDIST_VENDORED = "rockit_meco-0.2.8/rockit/external/acados/external/external"
#: BLASFEO targets by CPU feature (x86-64), best first; HPIPM's own target for each
TARGETS = {
    "X64_INTEL_HASWELL": ("avx2", "fma"),
    "X64_INTEL_SANDY_BRIDGE": ("avx",),
    "X64_INTEL_CORE": ("sse3",),
    "GENERIC": (),
}
HPIPM_TARGET = {"X64_INTEL_HASWELL": "AVX", "X64_INTEL_SANDY_BRIDGE": "AVX"}
#: ``UUV_OCP_HPIPM``: ``auto`` (native build if installed and intact, else the wheel's),
#: ``wheel`` or ``native`` (an error if there is none)
HPIPM_ENV = "UUV_OCP_HPIPM"
HPIPM_CHOICES = ("auto", "wheel", "native")
#: ``UUV_OCP_HPIPM_BUILD``: ``auto`` (unset: build the native HPIPM the first time a C step needs
#: it, see :func:`for_c_step`) or ``never`` (keep the wheel's until ``uuv-ocp hpipm build``)
HPIPM_BUILD_ENV = "UUV_OCP_HPIPM_BUILD"
HPIPM_BUILD_CHOICES = ("auto", "never")
#: ``<cache>/hpipm/`` file recording a failed first-need build (not retried until it is removed
#: or ``uuv-ocp hpipm build`` succeeds)
FAILED_MARKER = "first-need-failed.json"
_KEY = re.compile(r"[0-9a-f]{16}")
_SHA256 = re.compile(r"[0-9a-f]{64}")


class NativeHpipmError(RuntimeError):
    """The native build failed, or a build in the cache is refused (the message says why)."""


class HpipmChoiceError(NativeHpipmError, ValueError):
    """``UUV_OCP_HPIPM=native`` but no intact native build: a bad setting, refused up front."""


@dataclass(frozen=True)
class NativeHpipm:
    """One native build of BLASFEO and HPIPM (see the module doc).

    Attributes
    ----------
    directory : pathlib.Path
        ``<cache>/hpipm/<key>``: ``lib/`` (``libhpipm.a``, ``libblasfeo.a``), ``include/blasfeo``,
        ``include/hpipm`` and ``manifest.json``.
    target : str
        BLASFEO's target (a key of :data:`TARGETS`).
    digest : str
        SHA-256 of the manifest (libraries and headers): part of the step's cache key.
    """

    directory: Path
    target: str
    digest: str

    def link_flags(self) -> tuple[str, ...]:
        """Compiler and linker arguments linking both static libraries, their symbols hidden."""
        lib = self.directory / "lib"
        return (
            f"-I{self.directory / 'include' / 'hpipm'}",
            f"-I{self.directory / 'include' / 'blasfeo'}",
            str(lib / "libhpipm.a"),
            str(lib / "libblasfeo.a"),
            "-Wl,--exclude-libs,ALL",
            f"-DUUV_OCP_HPIPM_BUILD=0x{self.digest[:12]}",  # a rebuilt library changes the key
        )


def cpu_target(flags: set[str] | None = None) -> str:
    """BLASFEO's best target for this CPU (``flags``: the CPU's feature flags, else read).

    x86-64 only (``/proc/cpuinfo``); any other machine, or flags that cannot be read, gets
    ``GENERIC``, the kernels the wheel already has.
    """
    if flags is None:
        if platform.machine().lower() not in ("x86_64", "amd64"):
            return "GENERIC"
        try:
            text = Path("/proc/cpuinfo").read_text()
        except OSError:
            return "GENERIC"
        line = next((ln for ln in text.splitlines() if ln.startswith("flags")), "")
        flags = set(line.partition(":")[2].split())
    if "pni" in flags:  # /proc/cpuinfo spells SSE3 "pni"
        flags = flags | {"sse3"}
    return next(target for target, needs in TARGETS.items() if set(needs) <= flags)


def fetch_sources(destination: Path, log: Callable[[str], None] = print) -> Path:
    """Download the pinned ``rockit-meco`` sdist, check its SHA-256, extract BLASFEO and HPIPM.

    Returns the folder holding ``blasfeo/`` and ``hpipm/``.

    Raises
    ------
    NativeHpipmError
        ``pip download`` failed (no network to the package index?) or the archive's digest is
        not the pinned one.
    """
    spec = f"{SDIST_NAME}=={SDIST_VERSION}"
    log(f"fetching {spec} (source distribution, BLASFEO and HPIPM inside) with pip")
    command = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--no-binary", ":all:"]
    run = subprocess.run([*command, spec, "-d", str(destination)], capture_output=True, text=True)
    archives = sorted(destination.glob("rockit_meco-*.tar.gz"))
    if run.returncode or not archives:
        raise NativeHpipmError(f"pip download {spec} failed: {run.stderr.strip()[-400:]}")
    digest = _file_digest(archives[0])
    if digest != SDIST_SHA256:
        raise NativeHpipmError(f"{archives[0].name}: SHA-256 {digest}, expected the pinned {SDIST_SHA256}")
    sources = destination / "sources"
    with tarfile.open(archives[0]) as archive:
        members = [
            m
            for m in archive.getmembers()
            if m.name.startswith((f"{SDIST_VENDORED}/blasfeo/", f"{SDIST_VENDORED}/hpipm/"))
        ]
        archive.extractall(destination / "unpacked", members=members, filter="data")
    (destination / "unpacked" / SDIST_VENDORED).rename(sources)
    return sources


def build(
    source: str | os.PathLike[str] | None = None,
    target: str = "auto",
    cache: str | os.PathLike[str] | None = None,
    jobs: int = 2,
    log: Callable[[str], None] = print,
) -> NativeHpipm:
    """Build BLASFEO and HPIPM for ``target`` into the cache and make them the ones in use.

    Parameters
    ----------
    source : path-like, optional
        Folder with ``blasfeo/`` and ``hpipm/`` source trees; default: the pinned sdist
        (:func:`fetch_sources`).
    target : str
        A key of :data:`TARGETS`, or ``"auto"`` (:func:`cpu_target`).
    cache : path-like, optional
        Default :func:`uuv_ocp.native.compile.default_cache_directory`.
    jobs : int
        Parallel ``make`` jobs.
    log : callable
        Receives one line per stage (the build takes about a minute on two cores).

    Raises
    ------
    ValueError
        ``target`` unknown, ``source`` without both trees, or ``jobs`` < 1.
    NativeHpipmError
        The download or a ``make`` failed (its last output lines are in the message).
    """
    chosen = cpu_target() if target == "auto" else target
    if chosen not in TARGETS:
        raise ValueError(f"target must be 'auto' or one of {list(TARGETS)}, got {target!r}")
    if not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1:
        raise ValueError(f"jobs must be an int >= 1, got {jobs!r}")
    if source is not None:
        missing = [name for name in ("blasfeo", "hpipm") if not (Path(source) / name / "Makefile").is_file()]
        if missing:
            raise ValueError(f"source must hold blasfeo/ and hpipm/ source trees; {source} lacks {missing}")
    compiler = find_c_compiler()
    root = secure_directory(_root(cache).parent)  # the cache itself: checked (created 0700) first
    root = secure_directory(root / "hpipm")
    with tempfile.TemporaryDirectory(dir=root, prefix=".build-") as scratch:
        work = Path(scratch)
        if source is None:
            trees = fetch_sources(work, log)
        else:
            trees = work / "sources"
            for name in ("blasfeo", "hpipm"):
                shutil.copytree(Path(source) / name, trees / name, symlinks=False)
        version = subprocess.run([compiler, "--version"], capture_output=True, text=True).stdout
        key = hashlib.sha256(
            f"{_tree_digest(trees)}|{chosen}|{version.splitlines()[0] if version else compiler}".encode()
        ).hexdigest()[:16]
        blasfeo, hpipm = trees / "blasfeo", trees / "hpipm"
        (blasfeo / "lib").mkdir(exist_ok=True)  # BLASFEO's Makefile moves its library there
        (hpipm / "lib").mkdir(exist_ok=True)
        log(f"building BLASFEO (TARGET={chosen}) with {compiler}")
        _make(blasfeo, jobs, ["static_library", f"TARGET={chosen}", "BLAS_API=0", f"CC={compiler}"])
        hpipm_target = HPIPM_TARGET.get(chosen, "GENERIC")
        log(f"building HPIPM (TARGET={hpipm_target})")
        arguments = [f"TARGET={hpipm_target}", f"BLASFEO_PATH={blasfeo}", f"CC={compiler}"]
        _make(hpipm, jobs, ["static_library", *arguments])
        staged = work / "install"
        (staged / "lib").mkdir(parents=True)
        shutil.copy2(blasfeo / "lib" / "libblasfeo.a", staged / "lib")
        shutil.copy2(hpipm / "lib" / "libhpipm.a", staged / "lib")
        shutil.copytree(blasfeo / "include", staged / "include" / "blasfeo")
        shutil.copytree(hpipm / "include", staged / "include" / "hpipm")
        manifest = {
            "target": chosen,
            "compiler": compiler,
            "source": "pinned sdist" if source is None else str(Path(source).resolve()),
            "files": {
                str(path.relative_to(staged)): _file_digest(path)
                for path in sorted(staged.rglob("*"))
                if path.is_file()
            },
        }
        (staged / "manifest.json").write_text(json.dumps(manifest, indent=1, sort_keys=True))
        _make_private(staged)
        final = root / key
        if final.exists():
            shutil.rmtree(final)
        os.replace(staged, final)
    digest = _file_digest(final / "manifest.json")
    pointer = {"key": key, "manifest_sha256": digest}
    _write_atomic(root / "native.json", json.dumps(pointer))
    (root / FAILED_MARKER).unlink(missing_ok=True)  # a first-need build may try again
    log(f"installed in {final}")
    return NativeHpipm(final, chosen, digest)


def installed(cache: str | os.PathLike[str] | None = None, *, strict: bool = False) -> NativeHpipm | None:
    """Return the build in use, checked file by file (``None``: there is none, or it is refused).

    Checked before anything of it is used (see the module doc): the folders (the cache,
    ``hpipm/``, the build's), ``native.json`` and its key, the manifest's SHA-256 and every file
    the manifest lists (no more, no fewer) with its own SHA-256, owner and mode.

    Parameters
    ----------
    cache : path-like, optional
        The cache folder; default :func:`uuv_ocp.native.compile.default_cache_directory`.
    strict : bool, default False
        Raise :class:`NativeHpipmError` for a refused build instead of warning.

    Returns
    -------
    NativeHpipm or None
        ``None`` when nothing is built (silently) or when the build is refused (one
        ``RuntimeWarning`` naming the file and the reason, unless ``strict``).

    Raises
    ------
    NativeHpipmError
        ``strict`` and the build is refused.
    """
    try:
        return _checked_build(_root(cache))
    except NativeHpipmError as error:
        if strict:
            raise
        warnings.warn(
            f"native HPIPM build not used ({error}); rebuild it with `uuv-ocp hpipm build`",
            RuntimeWarning,
            stacklevel=2,
        )
        return None


def _checked_build(root: Path) -> NativeHpipm | None:
    """Return the build ``root/native.json`` names, checked (``None``: no ``native.json``)."""
    pointer_path = root / "native.json"
    if not os.path.lexists(pointer_path):
        return None
    try:
        secure_directory(root.parent, create=False)
        secure_directory(root, create=False)
        pointer = json.loads(read_private_file(pointer_path))
        if not isinstance(pointer, dict):
            raise ValueError(f"{pointer_path} holds no JSON object")
        key, recorded = pointer.get("key"), pointer.get("manifest_sha256")
        if not isinstance(key, str) or not _KEY.fullmatch(key):
            # never a path: an absolute or ../ key would point the C step at anybody's headers
            raise ValueError(f"{pointer_path}: key must be 16 hex digits, got {key!r}")
        if not isinstance(recorded, str) or not _SHA256.fullmatch(recorded):
            raise ValueError(f"{pointer_path}: manifest_sha256 must be 64 hex digits, got {recorded!r}")
        directory = root / key
        found = _private_tree(directory)
        manifest_bytes = read_private_file(directory / "manifest.json")
        if hashlib.sha256(manifest_bytes).hexdigest() != recorded:
            raise ValueError(f"{directory / 'manifest.json'} does not match {pointer_path}")
        manifest = json.loads(manifest_bytes)
        files = manifest["files"]
        if not isinstance(files, dict) or not all(isinstance(v, str) for v in files.values()):
            raise ValueError(f"{directory / 'manifest.json'}: files must map names to SHA-256 digests")
        listed = set(files) | {"manifest.json"}
        if found != listed:
            extra, missing = sorted(found - listed), sorted(listed - found)
            raise ValueError(
                f"{directory} does not hold exactly the files of its manifest "
                f"(not listed: {extra[:5]}, missing: {missing[:5]})"
            )
        for name, expected in files.items():
            if hashlib.sha256(read_private_file(directory / name)).hexdigest() != expected:
                raise ValueError(f"{directory / name} does not match its SHA-256 in the manifest")
        target = str(manifest["target"])
        if target not in TARGETS:
            raise ValueError(f"{directory / 'manifest.json'}: unknown target {target!r}")
    except (BuildDirectoryError, IntegrityError, OSError, ValueError, KeyError, TypeError) as error:
        raise NativeHpipmError(str(error)) from error
    return NativeHpipm(directory, target, recorded)


def _private_tree(directory: Path) -> set[str]:
    """Relative names of the files under ``directory``, after checking every entry of it.

    Every folder (``directory`` included) and every file must belong to the current user and
    not be writable by its group or others; a symbolic link or anything but a folder or a
    regular file is refused (``IntegrityError``, ``BuildDirectoryError``).
    """
    if os.path.islink(directory):
        raise BuildDirectoryError(f"build folder {directory} is a symbolic link")
    found: set[str] = set()
    pending = [directory]
    while pending:
        folder = pending.pop()
        secure_directory(folder, create=False)
        with os.scandir(folder) as entries:
            for entry in entries:
                path = Path(entry.path)
                if entry.is_dir(follow_symlinks=False):
                    pending.append(path)
                else:
                    check_private_file(path)  # refuses symbolic links, FIFOs, others' files
                    found.add(path.relative_to(directory).as_posix())
    return found


def _make_private(tree: Path) -> None:
    """Give every folder of ``tree`` mode ``0700`` and every file ``0600`` (umask aside).

    ``make`` and the copies create files with the umask's modes (0664 with umask 002): the
    group could then rewrite a header or library after its digest was recorded.
    """
    for folder, folders, files in os.walk(tree):
        os.chmod(folder, FOLDER_MODE)
        for name in files:
            path = os.path.join(folder, name)
            if not os.path.islink(path):
                os.chmod(path, FILE_MODE)
        for name in folders:
            if os.path.islink(os.path.join(folder, name)):
                raise NativeHpipmError(f"{os.path.join(folder, name)}: symbolic link in a build")


def selected(cache: str | os.PathLike[str] | None = None) -> NativeHpipm | None:
    """Return the native build to link per ``UUV_OCP_HPIPM`` (``None``: the wheel's libraries).

    Raises
    ------
    ValueError
        ``UUV_OCP_HPIPM`` is not one of :data:`HPIPM_CHOICES`.
    HpipmChoiceError
        ``UUV_OCP_HPIPM=native`` and no intact build is installed (a ``ValueError`` and a
        :class:`NativeHpipmError`).
    """
    choice = hpipm_choice()
    if choice == "wheel":
        return None
    if choice == "auto":
        return installed(cache)
    try:
        build_in_use = installed(cache, strict=True)
    except NativeHpipmError as error:
        raise HpipmChoiceError(
            f"{HPIPM_ENV}=native but the native build is refused ({error}): run `uuv-ocp hpipm "
            f"build`, or set {HPIPM_ENV} to 'auto' or 'wheel'"
        ) from error
    if build_in_use is None:
        raise HpipmChoiceError(
            f"{HPIPM_ENV}=native but no native HPIPM is built in {_root(cache)}: run `uuv-ocp "
            f"hpipm build`, or set {HPIPM_ENV} to 'auto' or 'wheel'"
        )
    return build_in_use


def build_policy() -> str:
    """Return the checked ``UUV_OCP_HPIPM_BUILD`` (unset or empty: ``"auto"``; case-insensitive).

    Raises
    ------
    ValueError
        It is not one of :data:`HPIPM_BUILD_CHOICES`.
    """
    return _environment_choice(HPIPM_BUILD_ENV, HPIPM_BUILD_CHOICES)


def _environment_choice(name: str, choices: Sequence[str]) -> str:
    """Return environment variable ``name`` lower-cased (unset or empty: ``"auto"``), one of ``choices``."""
    raw = os.environ.get(name, "")
    value = raw.strip().lower() or "auto"
    if value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(choices)}, got {raw!r}")
    return value


def first_need_decision(cache: str | os.PathLike[str] | None = None) -> str | None:
    """Why the C step keeps the wheel's HPIPM instead of building one now (``None``: build it).

    Asked only where ``UUV_OCP_HPIPM=auto`` found no build.  Not built: under
    ``UUV_OCP_HPIPM_BUILD=never``, where a build is recorded but refused by :func:`installed`
    (never replaced unasked), on a CPU without a better BLASFEO target than ``GENERIC`` (the
    wheel's own), or after a failed first-need build (its marker file in the cache).
    """
    if build_policy() == "never":
        return f"{HPIPM_BUILD_ENV}=never"
    if (_root(cache) / "native.json").exists():  # a build is recorded but refused: never replaced unasked
        return "the native build recorded in the cache is refused (see the warning above)"
    if cpu_target() == "GENERIC":
        return "this CPU has no BLASFEO kernels better than the wheel's GENERIC ones"
    marker = _root(cache) / FAILED_MARKER
    if marker.is_file():
        try:
            reason = str(json.loads(marker.read_text()).get("error", "unknown error"))
        except (OSError, ValueError):
            reason = "unreadable record"
        return f"its build failed before ({reason[:160]}; remove {marker} to retry)"
    return None


def for_c_step(
    cache: str | os.PathLike[str] | None = None, builder: Callable[..., NativeHpipm] | None = None
) -> NativeHpipm | None:
    """Return the native build a C step links, building it on this first need where allowed.

    ``UUV_OCP_HPIPM=auto`` with no build installed: unless :func:`first_need_decision` gives a
    reason, one line on stderr says that HPIPM/BLASFEO are being built for this CPU (a few
    minutes, once; cached and checksummed like ``uuv-ocp hpipm build``) and a progress bar
    follows the build's stages.  Where it is not built, or the build fails, one
    ``RuntimeWarning`` says so and why, and the wheel's HPIPM is linked: never silently slower.
    ``wheel`` and ``native`` behave as :func:`selected`.  ``builder``: :func:`build` (tests
    pass a stand-in).
    """
    native = selected(cache)
    if native is not None or hpipm_choice() != "auto":
        return native
    slower = "the C step links the CasADi wheel's HPIPM (TARGET_GENERIC BLASFEO, about 2x slower QPs)"
    reason = first_need_decision(cache)
    if reason is not None:
        warnings.warn(f"{slower}: {reason}; `uuv-ocp hpipm build` builds the native one", RuntimeWarning, 3)
        return None
    print(
        f"uuv_ocp: building HPIPM and BLASFEO for this CPU ({cpu_target()}), once: a few minutes, then "
        f"cached ({HPIPM_BUILD_ENV}=never skips this)",
        file=sys.stderr,
        flush=True,
    )
    bar = _StageBar(("fetching", "building BLASFEO", "building HPIPM", "installed"))
    try:
        return (builder or build)(cache=cache, log=bar.log)
    except (RuntimeError, OSError, ValueError) as error:  # no compiler, no network, a failed make
        bar.close()
        failure = f"{type(error).__name__}: {error}"
        try:
            root = secure_directory(secure_directory(_root(cache).parent) / "hpipm")
            _write_atomic(root / FAILED_MARKER, json.dumps({"error": failure}))
        except OSError:
            pass  # the warning below still says it; the next process tries again
        warnings.warn(f"{slower}: the native build failed ({failure})", RuntimeWarning, 3)
        return None


class _StageBar:
    """A one-line progress bar on stderr over the build's stages (its ``log`` lines)."""

    def __init__(self, stages: tuple[str, ...]) -> None:
        self.stages, self.done, self.start = stages, 0, time.monotonic()

    def log(self, line: str) -> None:
        for index, stage in enumerate(self.stages):
            if line.startswith(stage):
                self.done = max(self.done, index + 1)
        width = len(self.stages)
        bar = "#" * self.done + "-" * (width - self.done)
        end = "\n" if self.done == width else ""
        elapsed = time.monotonic() - self.start
        text = f"\r  [{bar}] {self.done}/{width} {line[:60]:<60} {elapsed:5.0f} s"
        print(text, end=end, file=sys.stderr, flush=True)

    def close(self) -> None:
        print(file=sys.stderr, flush=True)


def hpipm_choice() -> str:
    """Return the checked ``UUV_OCP_HPIPM`` (unset or empty: ``"auto"``; case-insensitive).

    Raises
    ------
    ValueError
        It is not one of :data:`HPIPM_CHOICES`.
    """
    return _environment_choice(HPIPM_ENV, HPIPM_CHOICES)


def check_choice(native_needed: bool = True, cache: str | os.PathLike[str] | None = None) -> None:
    """Refuse a bad ``UUV_OCP_HPIPM`` up front, when a backend that reads it is built.

    The C step reads the setting only when it is built (at its first warm solve); a bad value
    found there would fail every step into the closed loop's fallback.  Called by the ``sqp-rti``
    backend's constructor.

    Parameters
    ----------
    native_needed : bool, default True
        Whether the backend builds the C step (``qpsol="hpipm-ocp"``): then
        ``UUV_OCP_HPIPM=native`` also needs an intact native build.  Otherwise only the value is
        checked.
    cache : path-like, optional
        The cache folder; default :func:`uuv_ocp.native.compile.default_cache_directory`.

    Raises
    ------
    ValueError
        ``UUV_OCP_HPIPM`` is not one of :data:`HPIPM_CHOICES`, or it is ``native`` (and the C
        step is built) but no intact native build is installed (:class:`HpipmChoiceError`, also a
        :class:`NativeHpipmError`).
    """
    if hpipm_choice() == "native" and native_needed:
        selected(cache)


def old_partial_condensing(include: Path) -> bool:
    """Whether this HPIPM has the partial condensing of version ≤ 0.1.2 (acados' copy).

    Read from the header: there ``d_part_cond_qp_expand_sol`` also takes the condensed QP.  The
    C step then passes it, and condenses the whole QP in the feedback phase (see rti_hpipm.c).
    """
    header = (include / "hpipm_d_part_cond.h").read_text()
    match = re.search(r"d_part_cond_qp_expand_sol\(([^)]*)\)", header)
    return match is not None and match.group(1).count(",") == 5


def _root(cache: str | os.PathLike[str] | None) -> Path:
    return Path(os.path.abspath(cache if cache is not None else default_cache_directory())) / "hpipm"


def _make(folder: Path, jobs: int, arguments: list[str]) -> None:
    run = subprocess.run(["make", f"-j{jobs}", *arguments], cwd=folder, capture_output=True, text=True)
    if run.returncode:
        tail = "\n".join((run.stdout + run.stderr).strip().splitlines()[-15:])
        raise NativeHpipmError(f"make {' '.join(arguments)} in {folder.name} failed:\n{tail}")


def _file_digest(path: Path) -> str:
    hasher = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            hasher.update(block)
    return hasher.hexdigest()


def _tree_digest(folder: Path) -> str:
    hasher = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        hasher.update(str(path.relative_to(folder)).encode())
        hasher.update(_file_digest(path).encode())
    return hasher.hexdigest()


def _write_atomic(path: Path, text: str) -> None:
    _write_private(path, text.encode())
