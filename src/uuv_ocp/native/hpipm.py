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
``<cache>/hpipm/<key>/`` (key: the sources' digest, the target and the compiler) with a manifest
of SHA-256 digests of every library and header; ``<cache>/hpipm/native.json`` names the build
in use.  Both static libraries are linked into the step's shared library with their symbols
hidden, so they never meet the wheel's ``libhpipm`` that CasADi itself loads.
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
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

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


class NativeHpipmError(RuntimeError):
    """The native build failed, or ``UUV_OCP_HPIPM=native`` found no intact build."""


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
        Default :func:`uuv_ocp.codegen.default_cache_directory`.
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
    from uuv_ocp.native.compile import find_c_compiler, secure_directory

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
    root = secure_directory(_root(cache))
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
        final = root / key
        if final.exists():
            shutil.rmtree(final)
        os.replace(staged, final)
    digest = _file_digest(final / "manifest.json")
    pointer = {"key": key, "manifest_sha256": digest}
    _write_atomic(root / "native.json", json.dumps(pointer))
    log(f"installed in {final}")
    return NativeHpipm(final, chosen, digest)


def installed(cache: str | os.PathLike[str] | None = None) -> NativeHpipm | None:
    """Return the build in use, checked file by file against its manifest (``None``: there is none).

    A build that fails its check (a library or header changed, a manifest that is not the one
    recorded) is not used: one ``RuntimeWarning`` names the file, and ``None`` is returned.
    """
    root = _root(cache)
    pointer_path = root / "native.json"
    if not pointer_path.is_file():
        return None
    try:
        pointer = json.loads(pointer_path.read_text())
        directory = root / str(pointer["key"])
        digest = _file_digest(directory / "manifest.json")
        if digest != pointer["manifest_sha256"]:
            raise ValueError(f"{directory / 'manifest.json'} does not match {pointer_path}")
        manifest = json.loads((directory / "manifest.json").read_text())
        for name, expected in manifest["files"].items():
            if _file_digest(directory / name) != expected:
                raise ValueError(f"{directory / name} does not match its SHA-256 in the manifest")
        target = str(manifest["target"])
    except (OSError, ValueError, KeyError, TypeError) as error:
        warnings.warn(
            f"native HPIPM build not used ({error}); rebuild it with `uuv-ocp hpipm build`",
            RuntimeWarning,
            stacklevel=2,
        )
        return None
    return NativeHpipm(directory, target, digest)


def selected(cache: str | os.PathLike[str] | None = None) -> NativeHpipm | None:
    """Return the native build to link per ``UUV_OCP_HPIPM`` (``None``: the wheel's libraries).

    Raises
    ------
    ValueError
        ``UUV_OCP_HPIPM`` is not one of :data:`HPIPM_CHOICES`.
    NativeHpipmError
        ``UUV_OCP_HPIPM=native`` and no intact build is installed.
    """
    choice = os.environ.get(HPIPM_ENV, "auto").strip().lower() or "auto"
    if choice not in HPIPM_CHOICES:
        raise ValueError(f"{HPIPM_ENV} must be one of {HPIPM_CHOICES}, got {choice!r}")
    if choice == "wheel":
        return None
    build_in_use = installed(cache)
    if build_in_use is None and choice == "native":
        raise NativeHpipmError(f"{HPIPM_ENV}=native but no intact build: run `uuv-ocp hpipm build`")
    return build_in_use


def old_partial_condensing(include: Path) -> bool:
    """Whether this HPIPM has the partial condensing of version ≤ 0.1.2 (acados' copy).

    Read from the header: there ``d_part_cond_qp_expand_sol`` also takes the condensed QP.  The
    C step then passes it, and condenses the whole QP in the feedback phase (see rti_hpipm.c).
    """
    header = (include / "hpipm_d_part_cond.h").read_text()
    match = re.search(r"d_part_cond_qp_expand_sol\(([^)]*)\)", header)
    return match is not None and match.group(1).count(",") == 5


def _root(cache: str | os.PathLike[str] | None) -> Path:
    from uuv_ocp.codegen import default_cache_directory

    return Path(cache if cache is not None else default_cache_directory()) / "hpipm"


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
    handle, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(handle, "w") as stream:
        stream.write(text)
    os.replace(name, path)
