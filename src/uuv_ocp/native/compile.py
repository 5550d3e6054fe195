"""Generic C code generation for CasADi Functions: generate, compile, cache, load back, verify.

This is the problem-agnostic layer under ``generate_c``: it knows nothing about vehicles or
references, only about :class:`casadi.Function` objects.

* :func:`find_c_compiler` -- ``$CC`` if set, else the first of ``cc``, ``gcc``, ``clang`` on
  ``PATH``; :class:`CompilerNotFoundError` names exactly what was looked for.
* :func:`compile_functions` -- one :class:`casadi.CodeGenerator` (one ``.c`` and one ``.h``)
  holding all functions, compiled into a content-addressed shared library
  ``{name}_{digest[:16]}.so`` (SHA-256 of the C source, the compiler and its flags), loaded back
  with :func:`casadi.external` and checked against the symbolic functions on random inputs.
* :func:`load_or_fallback` -- the same, but without a working compiler it warns once and hands
  back the symbolic functions (CasADi's virtual machine).
* :func:`batched` -- map a one-candidate function over the columns of a population matrix.

Files are written atomically (temporary name, then :func:`os.replace`), so several processes may
share one build directory.  Because a library's file name is a digest of its content, a path is
never reused for different code: ``dlopen`` (which caches libraries by path) can never hand back
stale code.

Nothing is loaded that this module did not build, and nothing from a folder others can write:

* every library is built with a sidecar ``{library}.sha256`` holding the SHA-256 of its bytes
  (written atomically after the library); before a cached library is loaded (which runs its
  constructors) its bytes are hashed and compared with the sidecar.  A library without a
  sidecar or with a different hash (planted, modified or truncated, e.g. by a full disk or a
  killed build) is never loaded: it is rebuilt (see :func:`library_intact`);
* the library and its sidecar must be regular files (not symbolic links) owned by the current
  user and not writable by its group or others, and the library's ELF headers must lie inside
  the file: a library cut short whose sidecar was rewritten to match would otherwise kill the
  process with ``SIGBUS`` when the loader touches its missing pages;
* every file this module writes (sources, headers, libraries, sidecars) gets mode ``0600`` and
  every folder it creates ``0700``, whatever the umask;
* a build directory must be a directory owned by the current user, writable by it and not
  writable by its group or others (:func:`secure_directory`); a missing one is created with mode
  ``0700``.  Otherwise :class:`BuildDirectoryError` names the folder and the fix;
* libraries are always loaded by absolute path (a bare file name would make the system loader
  search ``LD_LIBRARY_PATH``).

The cache key of a library covers, besides its source and flags, the versions of uuv_ocp and
CasADi and the compiler's own ``--version`` line, so a cache shared by several installations
never hands one of them a library another built from different code or with another compiler.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import hmac
import os
import platform
import re
import secrets
import shlex
import shutil
import stat
import struct
import subprocess
import sys
import tempfile
import threading
import warnings
from collections.abc import Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from uuv_ocp import _version
from uuv_ocp.progress import SlowNotice

__all__ = [
    "COMPILER_CANDIDATES",
    "DEFAULT_FLAGS",
    "HASH_SUFFIX",
    "BuildDirectoryError",
    "CodegenError",
    "CompilationError",
    "CompiledLibrary",
    "CompilerNotFoundError",
    "FILE_MODE",
    "FOLDER_MODE",
    "VerificationError",
    "IntegrityError",
    "batched",
    "check_private_file",
    "compile_functions",
    "find_c_compiler",
    "jit_workspace",
    "library_intact",
    "load_or_fallback",
    "read_private_file",
    "secure_directory",
    "verify_library",
]

COMPILER_CANDIDATES: tuple[str, ...] = ("cc", "gcc", "clang")
"""Names searched on ``PATH`` (in this order) when ``CC`` is not set."""

DEFAULT_FLAGS: tuple[str, ...] = ("-O3", "-fPIC", "-shared")
"""Default compiler flags of :func:`compile_functions`."""

HASH_SUFFIX = ".sha256"
"""Suffix of the sidecar holding a library's SHA-256: ``{library}.sha256``."""

FILE_MODE = 0o600
"""Mode of every file this module writes (sources, headers, libraries, sidecars)."""

FOLDER_MODE = 0o700
"""Mode of every folder this module creates."""

CONDITIONING_MARGIN = 1000.0
"""An ``approximate`` function is judged where its symbolic twin moves by at most its tolerance / this.

Measured on the BlueROV2 obstacle course's SIMD ``cost_batch`` (20 000 random candidates): the
kernel's difference from the virtual machine was at most 51 times the twin's own one-ulp
movement, so a margin of 1000 keeps every judged element far inside the tolerance.
"""

CONDITIONING_DRAWS = 2
"""Evaluations of the symbolic twin at one-ulp-moved inputs that measure its conditioning."""

_PARALLELIZATIONS = ("serial", "unroll", "thread", "openmp")
_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_THREAD_WORKER = re.compile(r"^struct casadi_thread_worker(\d+)_args_t \{", re.MULTILINE)


class CodegenError(RuntimeError):
    """Base class of the errors raised by this module."""


class CompilerNotFoundError(CodegenError):
    """No usable C compiler; the message names the ``CC`` value or the names searched."""


class CompilationError(CodegenError):
    """The compiler failed, or its library could not be loaded.

    The message holds the command and the compiler's standard error.
    """


class VerificationError(CodegenError):
    """A compiled function disagrees with its symbolic twin beyond the tolerance."""


class BuildDirectoryError(CodegenError):
    """A build directory that code must not be loaded from (or written to).

    Not a directory, not creatable, not writable, owned by another user, or writable by its
    group or by others; the message names the folder and the fix.
    """


class IntegrityError(CodegenError):
    """A library's bytes do not match the SHA-256 its build recorded (or none was recorded)."""


def default_cache_directory() -> Path:
    """``$UUV_OCP_CACHE`` or ``~/.cache/uuv_ocp``: where solver builds are kept (absolute).

    An empty ``UUV_OCP_CACHE`` counts as unset; a relative one is taken relative to the current
    directory at the time of the call.  The folder is created with mode ``0700`` by the first
    build and must stay owned by the user and not writable by others.
    """
    configured = os.environ.get("UUV_OCP_CACHE", "").strip()
    folder = Path(configured) if configured else Path.home() / ".cache" / "uuv_ocp"
    return Path(os.path.abspath(folder))


def secure_directory(directory: str | os.PathLike[str], *, create: bool = True) -> Path:
    """Absolute path of ``directory``, created (mode ``0700``) if missing, checked safe.

    Safe means: a directory (symbolic links are followed) owned by the current user, writable by
    it, and not writable by its group or by others, so that nobody else can plant or replace a
    library in it.

    Parameters
    ----------
    directory : path-like
        The folder; a relative path is taken relative to the current directory now (``""`` is
        the current directory).
    create : bool, default True
        Create a missing folder (and its parents) with mode ``0700``; otherwise a missing folder
        is an error.

    Returns
    -------
    pathlib.Path
        The absolute path.

    Raises
    ------
    BuildDirectoryError
        The folder is missing (with ``create=False``) or cannot be created, is not a directory,
        is owned by another user, is group- or world-writable, or is not writable by the current
        user.  The message names the folder and what to do.
    """
    path = Path(os.path.abspath(os.fspath(directory)))
    if create and not path.exists():
        missing = [path]
        while not os.path.lexists(missing[-1].parent) and missing[-1].parent != missing[-1]:
            missing.append(missing[-1].parent)
        try:
            # every folder created here is private, its parents too: with umask 002 a missing
            # cache root would otherwise come out 0775 and let the group rename its content
            for folder in reversed(missing):
                try:
                    folder.mkdir(mode=FOLDER_MODE)
                    folder.chmod(FOLDER_MODE)  # mkdir's mode is reduced by the umask
                except FileExistsError:
                    pass  # created meanwhile by another process: checked below like any other
        except OSError as error:
            raise BuildDirectoryError(
                f"cannot create the build folder {path}: {error.strerror or error}; "
                "choose a writable folder (for the solvers' cache: set UUV_OCP_CACHE)"
            ) from error
    try:
        status = path.stat()
    except OSError as error:
        raise BuildDirectoryError(f"build folder {path} is not usable: {error.strerror or error}") from error
    if not stat.S_ISDIR(status.st_mode):
        raise BuildDirectoryError(f"build folder {path} is not a directory; choose another folder")
    if hasattr(os, "geteuid") and status.st_uid != os.geteuid():
        raise BuildDirectoryError(
            f"build folder {path} is owned by uid {status.st_uid}, not by the current user "
            f"(uid {os.geteuid()}): code in it could be replaced by that user, so nothing is built "
            "or loaded there; use a folder of your own (for the solvers' cache: set UUV_OCP_CACHE)"
        )
    if status.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise BuildDirectoryError(
            f"build folder {path} is writable by its group or by others (mode "
            f"{stat.S_IMODE(status.st_mode):04o}): anyone with that access could plant a library "
            f"that this process would load; run `chmod go-w {shlex.quote(str(path))}` or use "
            "another folder (for the solvers' cache: set UUV_OCP_CACHE)"
        )
    if not os.access(path, os.W_OK | os.X_OK):
        raise BuildDirectoryError(
            f"build folder {path} is not writable by the current user; run "
            f"`chmod u+wx {shlex.quote(str(path))}` or use another folder "
            "(for the solvers' cache: set UUV_OCP_CACHE)"
        )
    return path


def _sidecar(library: Path) -> Path:
    return library.with_name(library.name + HASH_SUFFIX)


def _file_sha256(path: Path) -> str:
    hasher = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            hasher.update(block)
    return hasher.hexdigest()


class _Refused(Exception):
    """A file that must not be trusted; ``args[0]`` says why (completes "refusing X: ...")."""


def _unsafe(status: os.stat_result) -> str | None:
    """Why a file with this ``lstat``/``fstat`` must not be trusted, or ``None``."""
    if stat.S_ISLNK(status.st_mode):
        return "it is a symbolic link"
    if not stat.S_ISREG(status.st_mode):
        return "it is not a regular file"
    if hasattr(os, "geteuid") and status.st_uid != os.geteuid():
        return f"it is owned by uid {status.st_uid}, not by the current user (uid {os.geteuid()})"
    if status.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return (
            f"it is writable by its group or by others (mode {stat.S_IMODE(status.st_mode):04o}), "
            "so anyone with that access could have rewritten it"
        )
    return None


def _read_trusted(path: Path) -> bytes:
    """Return the bytes of ``path``, read through one descriptor whose file passed :func:`_unsafe`.

    Opened without following a symbolic link and without blocking (a FIFO planted at the path
    would otherwise hang the open); the checks run on the open descriptor, so the bytes read
    are those of the file checked.  Raises :class:`_Refused` (or ``OSError``: missing).
    """
    flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
    try:
        descriptor = os.open(path, flags | getattr(os, "O_CLOEXEC", 0))
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise _Refused("it is a symbolic link") from None
        raise
    try:
        reason = _unsafe(os.fstat(descriptor))
        if reason is not None:
            raise _Refused(reason)
        chunks = []
        while block := os.read(descriptor, 1 << 20):
            chunks.append(block)
        return b"".join(chunks)
    finally:
        os.close(descriptor)


def check_private_file(path: str | os.PathLike[str]) -> Path:
    """Check that ``path`` is a regular file of the current user that others cannot write.

    Refused: a symbolic link (never followed), anything but a regular file, a file owned by
    another user, or one writable by its group or by others.

    Returns
    -------
    pathlib.Path
        The absolute path.

    Raises
    ------
    IntegrityError
        The file is refused; the message names it and why.
    OSError
        It cannot be examined (e.g. it does not exist).
    """
    absolute = Path(os.path.abspath(os.fspath(path)))
    reason = _unsafe(os.lstat(absolute))
    if reason is not None:
        raise IntegrityError(f"refusing {absolute}: {reason}")
    return absolute


def read_private_file(path: str | os.PathLike[str]) -> bytes:
    """Return the bytes of ``path`` once :func:`check_private_file` accepts it (on the open file).

    Raises
    ------
    IntegrityError
        The file is refused (symbolic link, not a regular file, another owner, writable by its
        group or others); the message names it and why.
    OSError
        It cannot be read.
    """
    absolute = Path(os.path.abspath(os.fspath(path)))
    try:
        return _read_trusted(absolute)
    except _Refused as refusal:
        raise IntegrityError(f"refusing {absolute}: {refusal}") from None


_ELF_MAGIC = b"\x7fELF"
_ET_DYN, _SHT_NOBITS = 3, 8
#: per ELF class (1: 32-bit, 2: 64-bit): file header after ``e_ident`` (from ``e_type`` to
#: ``e_shstrndx``), a program header, a section header (field order of <elf.h>)
_ELF_LAYOUT = {
    1: ("HHIIIIIHHHHHH", "IIIIIIII", "IIIIIIIIII"),
    2: ("HHIQQQIHHHHHH", "IIQQQQQQ", "IIQQQQIIQQ"),
}


def _elf_problem(data: bytes) -> str | None:
    """Why ``data`` is no complete ELF shared library (``None``: it is one, or not an ELF platform).

    The loader maps a library's segments as the program headers say; a file cut short maps
    pages past its end, and touching them raises ``SIGBUS``.  So the file header, both header
    tables, every segment and every section that occupies file space must lie inside ``data``.
    """
    if sys.platform.startswith(("darwin", "win")):  # Mach-O / PE: not parsed; the hash decides
        return None
    if data[:4] != _ELF_MAGIC or len(data) < 16:
        return "it is not an ELF file"
    elf_class, encoding = data[4], data[5]
    if elf_class not in _ELF_LAYOUT or encoding not in (1, 2):
        return f"its ELF identification is invalid (class {elf_class}, encoding {encoding})"
    order = "<" if encoding == 1 else ">"
    header, segment, section = (struct.Struct(order + layout) for layout in _ELF_LAYOUT[elf_class])
    size = len(data)
    if size < 16 + header.size:
        return f"its ELF header is cut short ({size} bytes)"
    fields = header.unpack_from(data, 16)
    e_type, phoff, shoff, phentsize, phnum, shentsize, shnum = (fields[i] for i in (0, 4, 5, 8, 9, 10, 11))
    if e_type != _ET_DYN:
        return f"it is not a shared library (ELF type {e_type})"
    if phnum and phentsize != segment.size or shnum and shentsize != section.size:
        return "its ELF header gives header sizes of another ELF class"
    end_of_file = f"past the end of the file ({size} bytes): truncated"
    tables = (("program", phoff, phnum, segment), ("section", shoff, shnum, section))
    for what, offset, count, entry in tables:
        if count and offset + count * entry.size > size:
            return f"its {what} header table ends {end_of_file}"
    for index in range(phnum):
        values = segment.unpack_from(data, phoff + index * segment.size)
        offset, filesz = (values[1], values[4]) if elf_class == 1 else (values[2], values[5])
        if offset + filesz > size:
            return f"its segment {index} ends at byte {offset + filesz}, {end_of_file}"
    for index in range(shnum):
        values = section.unpack_from(data, shoff + index * section.size)
        kind, offset, length = values[1], values[4], values[5]
        if kind != _SHT_NOBITS and offset + length > size:
            return f"its section {index} ends at byte {offset + length}, {end_of_file}"
    return None


def _library_problem(path: Path) -> str | None:
    """Why ``path`` must not be loaded (see :func:`library_intact`), or ``None``."""
    try:
        recorded = _read_trusted(_sidecar(path)).decode("ascii").strip()
    except _Refused as refusal:
        return f"its sidecar {_sidecar(path).name}: {refusal}"
    except (OSError, UnicodeDecodeError):
        return f"it has no readable sidecar {_sidecar(path).name} (not built by uuv_ocp)"
    if not re.fullmatch(r"[0-9a-f]{64}", recorded):
        return f"its sidecar {_sidecar(path).name} holds no SHA-256"
    try:
        data = _read_trusted(path)
    except _Refused as refusal:
        return str(refusal)
    except OSError as error:
        return f"it cannot be read ({error.strerror or error})"
    if not hmac.compare_digest(hashlib.sha256(data).hexdigest(), recorded):
        return (
            f"its content does not match the SHA-256 recorded by its build in {_sidecar(path).name} "
            "(modified, truncated or not built by uuv_ocp)"
        )
    return _elf_problem(data)


def library_intact(library: str | os.PathLike[str]) -> bool:
    """Whether ``library`` may be loaded: checked file, matching SHA-256, complete ELF headers.

    Not intact: a library without its sidecar ``{library}.sha256`` (not built here), with a
    malformed one, or whose bytes hash differently (modified, replaced or truncated); a library
    or sidecar that is a symbolic link, not a regular file, owned by another user or writable by
    its group or by others; a library whose ELF headers point past its end (cut short, even with
    a sidecar rewritten to match).  Nothing is loaded: only the bytes are read.
    """
    return _library_problem(Path(os.path.abspath(os.fspath(library)))) is None


def verify_library(library: str | os.PathLike[str]) -> Path:
    """Check ``library`` before it is loaded; return its absolute path.

    Raises
    ------
    BuildDirectoryError
        Its folder is not safe (see :func:`secure_directory`).
    IntegrityError
        The library is not intact (see :func:`library_intact`); the message says why.
    """
    path = secure_directory(Path(library).parent, create=False) / Path(library).name
    problem = _library_problem(path)
    if problem is not None:
        raise IntegrityError(
            f"refusing to load {path}: {problem}; build it again (generate_c / compile_functions rebuild it)"
        )
    return path


def _write_private(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically with mode ``0600`` (temporary name, then rename)."""
    temporary = path.with_name(f".{path.name}-{os.getpid()}-{secrets.token_hex(6)}.tmp")
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
    descriptor = os.open(temporary, flags | getattr(os, "O_CLOEXEC", 0), FILE_MODE)
    try:
        try:
            os.fchmod(descriptor, FILE_MODE)  # the open's mode is reduced by the umask
            view = memoryview(data)
            while view:
                view = view[os.write(descriptor, view) :]
        finally:
            os.close(descriptor)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def _record_hash(built: Path, library: Path) -> None:
    """Write the sidecar of ``library`` (the hash of ``built``, its new content) atomically."""
    _write_private(_sidecar(library), (_file_sha256(built) + "\n").encode("ascii"))


_CWD_LOCK = threading.Lock()


@contextlib.contextmanager
def jit_workspace(directory: str | os.PathLike[str]) -> Iterator[str]:
    """Run CasADi's JIT (``compiler="shell"``) inside ``directory`` instead of the working directory.

    CasADi 3.8's ``nlpsol`` writes the generated source of its NLP functions (``jit_tmp*.c``) to
    the *current* directory, whatever its ``jit_options["directory"]`` (which only places the
    object file and the library).  Within this context the process works in ``directory``
    (checked by :func:`secure_directory`, created ``0700``); the working directory is restored
    on exit, even if it was renamed meanwhile.  Pass the yielded string (the folder with a
    trailing separator) as ``jit_options["directory"]``; CasADi removes its files when the
    function is released.

    The working directory is process wide: the context holds a lock, and nothing else in this
    package reads relative paths meanwhile (the JIT build is one call into CasADi).

    Raises
    ------
    BuildDirectoryError
        ``directory`` is not safe (see :func:`secure_directory`).
    """
    folder = secure_directory(directory)
    # CasADi writes its sources and library here with the umask's modes (0664 with umask 002)
    # and loads the library at once: a private folder keeps everybody else away from them
    folder.chmod(FOLDER_MODE)
    with _CWD_LOCK:
        previous = os.open(".", os.O_RDONLY) if hasattr(os, "fchdir") else None
        fallback = os.getcwd() if previous is None else ""
        try:
            os.chdir(folder)
            yield str(folder) + os.sep
        finally:
            if previous is not None:
                os.fchdir(previous)
                os.close(previous)
            else:
                os.chdir(fallback)


@dataclass(frozen=True)
class CompiledLibrary:
    """A generated (and normally compiled and loaded) set of CasADi functions.

    Attributes
    ----------
    path : pathlib.Path or None
        The shared library ``{name}_{digest[:16]}.so``; ``None`` when only sources were generated.
    source : pathlib.Path
        The generated C source ``{name}.c``.
    header : pathlib.Path
        The generated header ``{name}.h``.
    functions : dict[str, casadi.Function]
        Name -> function loaded from ``path`` with :func:`casadi.external` (empty without
        compilation).
    digest : str
        Hex SHA-256 of the C source, the compiler and the flags (the cache key).
    compiler : str
        The compiler used (``""`` when only sources were generated).
    max_error : dict[str, float]
        Name -> largest relative error, compiled vs symbolic, measured by the verification
        (empty when not verified).
    reused : bool
        Whether an intact library from an earlier build was loaded (no compilation).
    """

    path: Path | None
    source: Path
    header: Path
    functions: dict[str, ca.Function]
    digest: str
    compiler: str
    max_error: dict[str, float]
    reused: bool = False

    def __getitem__(self, name: str) -> ca.Function:
        """Return the loaded function called ``name``.

        Raises
        ------
        KeyError
            If no such function was loaded; the message lists the loaded names.
        """
        try:
            return self.functions[name]
        except KeyError:
            raise KeyError(f"no compiled function {name!r}; loaded: {sorted(self.functions)}") from None


def _resolve_executable(command: str, search_path: str) -> str | None:
    """Absolute path of ``command`` (a name searched on ``search_path`` or a path), or ``None``."""
    found = shutil.which(command, path=search_path)
    return str(Path(found).absolute()) if found else None


def find_c_compiler(env: Mapping[str, str] | None = None) -> str:
    """Find the C compiler: ``CC`` if set, else the first of ``cc``, ``gcc``, ``clang`` on PATH.

    Parameters
    ----------
    env : Mapping[str, str], optional
        Environment to read ``CC`` and ``PATH`` from; defaults to :data:`os.environ`.  A mapping
        without ``PATH`` searches :data:`os.defpath`.

    Returns
    -------
    str
        Absolute path of the compiler executable.

    Raises
    ------
    CompilerNotFoundError
        If ``CC`` is set but is not an executable (no fallback to ``PATH`` then: an explicit
        choice is never silently replaced), or if ``CC`` is unset (or empty) and none of
        ``cc``, ``gcc``, ``clang`` is on ``PATH``.  The message names what was looked for.
    """
    environment = os.environ if env is None else env
    search_path = environment.get("PATH", os.defpath)
    requested = environment.get("CC", "").strip()
    if requested:
        found = _resolve_executable(requested, search_path)
        if found is None:
            raise CompilerNotFoundError(
                f"C compiler not found: CC={requested!r} is not an executable file "
                f"(nor a command on PATH={search_path!r}); fix or unset CC"
            )
        return found
    for candidate in COMPILER_CANDIDATES:
        found = _resolve_executable(candidate, search_path)
        if found is not None:
            return found
    raise CompilerNotFoundError(
        "C compiler not found: CC is not set and none of "
        f"{', '.join(COMPILER_CANDIDATES)} is on PATH={search_path!r}; "
        "install a C compiler or set CC"
    )


def _digest(source_text: str, compiler: str, command_flags: Sequence[str]) -> str:
    """SHA-256 of the source text, the compiler, the flags and the toolchain (NUL separated).

    The toolchain (:func:`_toolchain`) is part of the key when a compiler is given, so one cache
    shared by several installations (checkouts, venvs) keeps their libraries apart.
    """
    hasher = hashlib.sha256()
    for part in (source_text, compiler, *command_flags, *(_toolchain(compiler) if compiler else ())):
        hasher.update(part.encode("utf-8"))
        hasher.update(b"\0")
    return hasher.hexdigest()


def _toolchain(compiler: str) -> tuple[str, ...]:
    """Return the versions of uuv_ocp and CasADi and the first line of ``compiler --version``.

    The compiler's version is read once per executable (path, size and modification time): an
    upgrade in place changes the key, so no library of the old compiler is reused.
    """
    try:
        status = os.stat(compiler)
        identity: tuple[object, ...] = (status.st_size, status.st_mtime_ns)
    except OSError:
        identity = ()
    casadi_version = str(getattr(ca, "__version__", ""))  # untyped in casadi's stubs
    package = f"uuv_ocp {_version.__version__}"  # read per call: a test changes it
    return (package, f"casadi {casadi_version}", _compiler_version(compiler, identity))


@functools.lru_cache(maxsize=16)
def _compiler_version(compiler: str, identity: tuple[object, ...]) -> str:
    """First line of ``compiler --version`` (``""`` if it cannot be run); cached per identity."""
    del identity  # part of the cache key only
    try:
        completed = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return ""
    lines = (completed.stdout or completed.stderr).strip().splitlines()
    return lines[0] if lines else ""


def _machine_key(flags: Sequence[str]) -> tuple[str, ...]:
    """Name the processor when ``flags`` tune for it (``-march=native``), else return ``()``.

    A library built for this processor's instruction set may not run on another one: the
    processor joins the cache key, so a shared cache directory never hands it to a different CPU.
    """
    if not any(flag.endswith("=native") for flag in flags):
        return ()
    identity = [platform.machine(), platform.processor()]
    with contextlib.suppress(OSError):
        lines = Path("/proc/cpuinfo").read_text().splitlines()
        for key in ("model name", "flags", "Features"):
            identity.extend(line for line in lines[:64] if line.startswith(key))
    return ("\n".join(dict.fromkeys(identity)),)


def _install(temporary: Path, final: Path) -> None:
    """Move ``temporary`` onto ``final`` atomically (mode ``0600``), unless ``final`` has its content.

    An existing ``final`` is kept (its time stamp unchanged) only if it is a file of this user
    that others cannot write; its mode is then set to ``0600`` as well.
    """
    temporary.chmod(FILE_MODE)
    with contextlib.suppress(OSError, _Refused):
        if _read_trusted(final) == temporary.read_bytes():
            final.chmod(FILE_MODE)
            return
    os.replace(temporary, final)


def _install_copy(staged: Path, final: Path) -> None:
    """Like :func:`_install` but keeps ``staged`` (it is still to be compiled)."""
    copy = staged.with_name(staged.name + ".copy")
    shutil.copyfile(staged, copy)
    _install(copy, final)


_HPIPM_ARG_COPY = "memcpy(&myarg, &p->hpipm_options, sizeof(struct d_ocp_qp_ipm_arg));"
_HPIPM_FIELD = re.compile(r"p\.hpipm_options\.(\w+) = ")
_HPIPM_FAILURE = re.compile(r"if \(d\.return_status!=0\) \{\s*return -1;\s*\}")


def _patch_hpipm(source_text: str) -> str:
    """Fix CasADi 3.8's generated HPIPM call, which copies a half-initialised argument struct.

    The generated ``casadi_hpipm_solve`` copies its option struct over HPIPM's whole
    ``d_ocp_qp_ipm_arg``, whose fields the generated code never set stay garbage; HPIPM then
    stopped at ``iter_max`` (status 1) on a QP the CasADi plugin solves in 11 iterations
    (measured on the RexROV RTI QP).  The patch sets HPIPM's defaults for the mode first and
    copies only the fields the generated code sets.  Sources without HPIPM are unchanged.
    """
    if _HPIPM_ARG_COPY not in source_text:
        return source_text
    fields = [f for f in dict.fromkeys(_HPIPM_FIELD.findall(source_text)) if f not in ("mode", "memsize")]
    replacement = "d_ocp_qp_ipm_arg_set_default((enum hpipm_mode) p->hpipm_options.mode, &myarg);" + "".join(
        f" myarg.{field} = p->hpipm_options.{field};" for field in fields
    )
    # HPIPM's status (max_iter, min_step) is no verdict on the step: like the Python backend,
    # the caller judges the QP solution by its linearised violation (an output), so a
    # non-converged IPM does not abort the whole Function and lose that solution
    source_text = _HPIPM_FAILURE.sub("", source_text)
    return source_text.replace(_HPIPM_ARG_COPY, replacement)


def _link_flags(source_text: str) -> list[str]:
    """Libraries to link: libm always; POSIX threads when a ``"thread"`` map was generated."""
    flags = ["-lm"]
    if "#include <pthread.h>" in source_text and not sys.platform.startswith("win"):
        flags.append("-pthread")
    return flags


def _compile(command: list[str], temporary: Path, final: Path) -> None:
    """Run ``command`` (which writes ``temporary``) and move the result onto ``final``.

    The SHA-256 of the new library is recorded in its sidecar right after the move.
    """
    try:
        completed = subprocess.run(command, capture_output=True, text=True, check=False)
    except OSError as error:
        temporary.unlink(missing_ok=True)
        raise CompilationError(f"could not run the C compiler: {shlex.join(command)}\n{error}") from error
    if completed.returncode != 0:
        temporary.unlink(missing_ok=True)
        raise CompilationError(
            f"C compilation failed (exit status {completed.returncode}): {shlex.join(command)}\n"
            f"--- compiler stderr ---\n{completed.stderr.strip()}"
        )
    try:
        temporary.chmod(FILE_MODE)  # the compiler's output mode follows the umask (0775 with 002)
        os.replace(temporary, final)
        _record_hash(final, final)
    except OSError:
        temporary.unlink(missing_ok=True)
        raise


def _load(names: Sequence[str], library: Path) -> dict[str, ca.Function]:
    """Load every function of ``library`` with :func:`casadi.external` (after its hash check)."""
    library = verify_library(library)  # absolute: a bare name would make dlopen search the path
    try:
        return {name: ca.external(name, str(library)) for name in names}
    except RuntimeError as error:
        raise CompilationError(f"could not load {library} with casadi.external: {error}") from error


def _relative_errors(compiled: np.ndarray, symbolic: np.ndarray) -> np.ndarray:
    """Element-wise ``|compiled - symbolic| / max(1, |symbolic|)``; NaN/inf must match exactly."""
    same_nonfinite = ~np.isfinite(symbolic) & (
        (np.isnan(symbolic) & np.isnan(compiled)) | (symbolic == compiled)
    )
    with np.errstate(invalid="ignore", over="ignore"):
        error = np.abs(compiled - symbolic) / np.maximum(1.0, np.abs(symbolic))
    error = np.where(same_nonfinite, 0.0, error)
    return np.where(np.isnan(error), np.inf, error)


def _relative_error(compiled: np.ndarray, symbolic: np.ndarray) -> float:
    """Largest ``|compiled - symbolic| / max(1, |symbolic|)``; NaN/inf must match exactly."""
    if compiled.size == 0:
        return 0.0
    return float(np.max(_relative_errors(compiled, symbolic)))


def _one_ulp_away(value: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``value`` with every entry moved one ulp up or down (random direction)."""
    up = rng.random(value.shape) < 0.5
    return np.where(up, np.nextafter(value, np.inf), np.nextafter(value, -np.inf))


def _well_conditioned(
    function: ca.Function,
    arguments: list[ca.DM],
    expected: list[ca.DM],
    rng: np.random.Generator,
    limit: float,
) -> list[np.ndarray]:
    """Per output, the elements that ``function`` itself reproduces to ``limit / CONDITIONING_MARGIN``.

    ``function`` (the symbolic twin) is evaluated again with every input moved by one ulp
    (:data:`CONDITIONING_DRAWS` random directions); an element that moves by more than
    ``limit / CONDITIONING_MARGIN`` (relative) is ill-conditioned there.
    """
    floor = [np.zeros(want.shape) for want in expected]  # DM.shape: numpy on a DM warns
    for _ in range(CONDITIONING_DRAWS):
        moved = [ca.DM(_one_ulp_away(np.asarray(a.full()), rng)) for a in arguments]
        for index, (got, want) in enumerate(zip(function.call(moved), expected, strict=True)):
            moved_by = _relative_errors(np.asarray(got.full()), np.asarray(want.full()))
            floor[index] = np.maximum(floor[index], moved_by)
    return [f <= limit / CONDITIONING_MARGIN for f in floor]


def _verify(
    symbolic: Sequence[ca.Function],
    compiled: Mapping[str, ca.Function],
    rng: np.random.Generator,
    tolerance: float,
    tolerances: Mapping[str, float] | None = None,
    approximate: Collection[str] = (),
) -> dict[str, float]:
    """Evaluate each compiled function and its symbolic twin on the same random dense inputs.

    ``tolerances`` overrides ``tolerance`` for the functions it names.  The functions named in
    ``approximate`` are compared only on the output elements where the twin is well conditioned
    (:func:`_well_conditioned`), at least half of them (see :func:`compile_functions`).
    """
    errors: dict[str, float] = {}
    for function in symbolic:
        name = function.name()
        arguments = [ca.DM(rng.uniform(-1.0, 1.0, size=function.size_in(i))) for i in range(function.n_in())]
        expected = function.call(arguments)
        obtained = compiled[name].call(arguments)
        limit = (tolerances or {}).get(name, tolerance)
        element_errors = [
            _relative_errors(np.asarray(got.full()), np.asarray(want.full()))
            for got, want in zip(obtained, expected, strict=True)
        ]
        if name in approximate:
            judged = _well_conditioned(function, arguments, expected, rng, limit)
            count = sum(int(mask.sum()) for mask in judged)
            total = sum(mask.size for mask in judged)
            if 2 * count < total:
                raise VerificationError(
                    f"compiled function {name!r} cannot be verified on these inputs: its symbolic "
                    f"twin itself moves by more than {limit / CONDITIONING_MARGIN:.1e} (relative) under "
                    f"one-ulp changes of its inputs at {total - count} of its {total} output elements"
                )
            element_errors = [error[mask] for error, mask in zip(element_errors, judged, strict=True)]
        error = max((float(np.max(e)) for e in element_errors if e.size), default=0.0)
        errors[name] = error
        if not error <= limit:
            raise VerificationError(
                f"compiled function {name!r} disagrees with its symbolic twin: max relative "
                f"error {error:.3e} > tolerance {limit:.1e}"
            )
    return errors


def _check_thread_workers(
    source_text: str, staged_source: Path, source: Path, staged_header: Path, header: Path
) -> None:
    """Refuse a source that CasADi generated with clashing ``"thread"`` map workers.

    CasADi 3.8 names the worker of a ``"thread"`` map after the mapped function, so two thread
    maps of the *same* function (e.g. two population sizes) in one file define the same worker
    twice and the C code does not compile.  :func:`batched` avoids it by mapping a distinct copy;
    maps built directly with ``Function.map`` can still hit it.  The sources are installed
    anyway, for inspection.
    """
    workers = _THREAD_WORKER.findall(source_text)
    clashing = sorted({w for w in workers if workers.count(w) > 1})
    if clashing:
        _install(staged_source, source)
        _install(staged_header, header)
        raise CompilationError(
            f"{source}: CasADi generated duplicate thread-map workers "
            f"({', '.join('casadi_thread_worker' + w for w in clashing)}): two 'thread' maps of "
            "the same function cannot share one C file; build them with uuv_ocp.native.compile."
            "batched (which maps a distinct copy) or use 'serial' for one of them"
        )


def _check_functions(functions: Sequence[ca.Function], name: str) -> list[ca.Function]:
    """Validate the arguments of :func:`compile_functions`."""
    if not _IDENTIFIER.fullmatch(name):
        raise ValueError(f"name must be a C identifier, got {name!r}")
    functions = list(functions)
    if not functions:
        raise ValueError("no functions to generate")
    names: set[str] = set()
    for function in functions:
        if not isinstance(function, ca.Function):
            raise TypeError(f"expected casadi.Function, got {type(function).__name__}")
        if function.name() in names:
            raise ValueError(f"two functions are called {function.name()!r}")
        names.add(function.name())
    return functions


def compile_functions(
    functions: Sequence[ca.Function],
    directory: str | os.PathLike[str],
    *,
    name: str = "uuv_ocp_gen",
    compile: bool = True,
    verify: bool = True,
    rng: np.random.Generator | None = None,
    cc: str | None = None,
    flags: Sequence[str] = DEFAULT_FLAGS,
    tolerance: float = 1e-12,
    tolerances: Mapping[str, float] | None = None,
    approximate: Collection[str] = (),
    extra_source: str = "",
    external: Sequence[ca.Function] = (),
    extra_header: str = "",
    link: Sequence[str] = (),
    prefix: str = "",
) -> CompiledLibrary:
    """Generate C code for ``functions``, compile it (cached), load it back and verify it.

    Parameters
    ----------
    functions : Sequence[casadi.Function]
        Functions to put in one C file; their names (unique, C identifiers) become the C symbols
        and the names passed to :func:`casadi.external`.
    directory : path-like
        Output directory (created with mode ``0700`` if missing; refused if it is owned by
        another user or writable by its group or others, see :func:`secure_directory`);
        receives ``{name}.c``, ``{name}.h``, ``{name}_{digest[:16]}.so`` and the library's
        ``.sha256`` sidecar.
    name : str, default ``"uuv_ocp_gen"``
        Base name of the generated files (a C identifier).
    compile : bool, default True
        If False, only write the sources: no compiler is looked for, ``path`` is ``None``,
        ``functions`` and ``max_error`` are empty and ``compiler`` is ``""``.
    verify : bool, default True
        Evaluate every compiled function and its symbolic twin on the same random dense inputs
        (uniform in [-1, 1], shapes ``f.size_in(i)``) and compare (``approximate`` ones only
        where the twin is well conditioned).
    rng : numpy.random.Generator, optional
        Source of the verification inputs; default ``numpy.random.default_rng(0)``.
    cc : str, optional
        Compiler (name on ``PATH`` or path); default :func:`find_c_compiler`.
    flags : Sequence[str], default ``("-O3", "-fPIC", "-shared")``
        Compiler flags; the command is ``[cc, *flags, source, "-o", library, "-lm"]``
        (plus ``-pthread`` when a ``"thread"`` map was generated).
    tolerance : float, default 1e-12
        Largest accepted ``|compiled - symbolic| / max(1, |symbolic|)``, element-wise.
    tolerances : Mapping[str, float], optional
        Per-function tolerances replacing ``tolerance`` for the functions named (e.g. a SIMD
        kernel whose own ``sin``/``cos`` differ from libm by a few ulp).
    approximate : Collection[str], default ()
        Names of functions (of ``functions`` or ``external``) that compute some operations only
        approximately (the SIMD kernel's ``sin``/``cos``, a few ulp from libm).  Where the
        symbolic twin is ill-conditioned, a few-ulp difference is amplified past any
        tolerance and says nothing about the compiled code (a 6-DOF rollout through ±90°
        pitch divides by cos θ ≈ 0: the twin itself moves by 1e-2 when its inputs move by one
        ulp).  So these are compared only on the output elements that the twin reproduces to
        their tolerance / :data:`CONDITIONING_MARGIN` when every input moves by one ulp
        (:data:`CONDITIONING_DRAWS` draws), at that same tolerance; fewer than half of the
        elements judged is a :class:`VerificationError`.
    extra_source : str, default ""
        Hand-written C appended to the generated source (it may call the generated functions,
        e.g. the all-C IGWO step); part of the digest.
    external : Sequence[casadi.Function], default ()
        Symbolic twins of functions that ``extra_source`` defines under CasADi's
        external-function ABI (e.g. a SIMD kernel): loaded and verified like the generated
        ones, under the twin's name.
    extra_header : str, default ""
        Declarations appended to the generated header (those of ``extra_source``'s exported
        functions); part of the digest through the source, which includes the header.
    link : Sequence[str], default ()
        Extra linker arguments placed after the source (libraries such as HPIPM's); part of
        the digest.
    prefix : str, default ""
        Put in front of every function's C symbol (``{prefix}{function}``, ``_work``, …);
        ``functions`` of the result stay keyed by the unprefixed names.  CasADi names its
        exported helpers after ``name``, so give each library its own ``name`` too: then two
        libraries can be linked into one program.  ``external`` functions must already be
        defined under ``{prefix}{name}`` by ``extra_source``.

    Returns
    -------
    CompiledLibrary
        Paths, loaded functions, digest, compiler and measured errors.

    Raises
    ------
    CompilerNotFoundError
        No compiler (see :func:`find_c_compiler`); ``cc`` not executable.
    CompilationError
        The compiler failed (message: command and compiler stderr) or the library did not load.
    BuildDirectoryError
        ``directory`` is not safe to build in or load from (see :func:`secure_directory`).
    VerificationError
        A compiled function differs from its symbolic twin by more than ``tolerance``.
    ValueError, TypeError
        Invalid arguments (no functions, duplicate names, non-identifier ``name``).

    Notes
    -----
    The library is content addressed: if ``{name}_{digest[:16]}.so`` already exists and is intact
    (:func:`library_intact`: its own file, its bytes match the SHA-256 in its sidecar, complete
    ELF headers) it is loaded without recompiling; otherwise (no sidecar, planted, modified,
    truncated, a symbolic link, writable by others) it is replaced by a new build before anything
    is loaded.  The digest covers the source text, the compiler (path and ``--version``), the
    flags and the versions of uuv_ocp and CasADi.  Every file written gets mode ``0600``.
    """
    functions, external = list(functions), list(external)
    if prefix and not _IDENTIFIER.fullmatch(prefix):
        raise ValueError(f"prefix must be empty or a C identifier, got {prefix!r}")
    _check_functions([*functions, *external], name)
    compiled_names = sorted(function.name() for function in (*functions, *external))
    if isinstance(approximate, str) or not set(approximate) <= set(compiled_names):
        raise ValueError(
            f"approximate must be a collection of names from {compiled_names}, got {approximate!r}"
        )
    generated = [_copy(function, prefix + function.name()) for function in functions] if prefix else functions
    for label, value in [
        ("tolerance", tolerance),
        *((f"tolerances[{k!r}]", v) for k, v in (tolerances or {}).items()),
    ]:
        if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
            raise ValueError(f"{label} must be a number >= 0, got {value!r}")
    directory = secure_directory(directory)
    flags = tuple(flags)

    generator = ca.CodeGenerator(f"{name}.c", {"with_header": True})
    for function in generated:
        generator.add(function)

    source = directory / f"{name}.c"
    header = directory / f"{name}.h"
    staging = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=directory))
    try:
        # The prefix is pasted in front of the file names: it needs the trailing separator.
        generator.generate(str(staging) + os.sep)
        staged_source, staged_header = staging / source.name, staging / header.name
        source_text = _patch_hpipm(staged_source.read_text())
        if extra_source:
            source_text = f"{source_text}\n{extra_source}"
        staged_source.write_text(source_text)
        if extra_header:
            header_text = staged_header.read_text()
            closing = header_text.rfind("#ifdef __cplusplus")
            if closing < 0:
                header_text = f"{header_text}\n{extra_header}\n"
            else:  # inside the header's extern "C" block
                header_text = f"{header_text[:closing]}{extra_header}\n{header_text[closing:]}"
            staged_header.write_text(header_text)
            source_text = f"{source_text}\n/* header */\n{extra_header}"

        if not compile:
            _install(staged_source, source)
            _install(staged_header, header)
            return CompiledLibrary(
                path=None,
                source=source,
                header=header,
                functions={},
                digest=_digest(source_text, "", flags),
                compiler="",
                max_error={},
            )

        _check_thread_workers(source_text, staged_source, source, staged_header, header)
        if cc is None:
            compiler = find_c_compiler()
        else:
            resolved = _resolve_executable(cc, os.environ.get("PATH", os.defpath))
            if resolved is None:
                raise CompilerNotFoundError(f"C compiler not found: cc={cc!r} is not executable")
            compiler = resolved
        link = [*_link_flags(source_text), *link]
        digest = _digest(source_text, compiler, (*flags, *link, *_machine_key(flags)))
        library = directory / f"{name}_{digest[:16]}.so"
        reused = library_intact(library)
        if not reused:
            # A unique name, not pre-created (mkstemp's 0600 mode would leak into the library).
            temporary = directory / f".{library.stem}-{os.getpid()}-{secrets.token_hex(6)}.so.tmp"
            command = [compiler, *flags, str(staged_source), "-o", str(temporary), *link]
            _install_copy(staged_source, source)  # installed first: inspectable on failure
            _install_copy(staged_header, header)
            try:
                # a compile takes seconds to minutes (the swarms' and sqp-rti's first use): say so
                with SlowNotice(f"uuv_ocp: compiling {name} (first use; cached in {directory})"):
                    _compile(command, temporary, library)
            except CompilationError as error:
                raise CompilationError(f"{error}\n(generated source kept at {source})") from None
        _install(staged_source, source)
        _install(staged_header, header)
    finally:
        shutil.rmtree(staging, ignore_errors=True)

    names = [function.name() for function in (*functions, *external)]
    prefixed = _load([prefix + entry for entry in names], library)
    loaded = {entry: prefixed[prefix + entry] for entry in names}
    errors: dict[str, float] = {}
    if verify:
        generator_rng = np.random.default_rng(0) if rng is None else rng
        errors = _verify([*functions, *external], loaded, generator_rng, tolerance, tolerances, approximate)
    return CompiledLibrary(
        path=library,
        source=source,
        header=header,
        functions=loaded,
        digest=digest,
        compiler=compiler,
        max_error=errors,
        reused=reused,
    )


def load_or_fallback(
    functions: Sequence[ca.Function],
    directory: str | os.PathLike[str],
    **kw,
) -> tuple[dict[str, ca.Function], CompiledLibrary | None]:
    """Compiled functions when possible, else the symbolic ones (CasADi's virtual machine).

    Parameters
    ----------
    functions : Sequence[casadi.Function]
        As for :func:`compile_functions`.
    directory : path-like
        As for :func:`compile_functions`.
    **kw
        Keyword arguments of :func:`compile_functions`.

    Returns
    -------
    functions : dict[str, casadi.Function]
        Name -> compiled function, or name -> symbolic function on fallback (or when
        ``compile=False``).
    library : CompiledLibrary or None
        The build, or ``None`` on fallback.

    Warns
    -----
    RuntimeWarning
        Once per call, when no compiler is found, compilation or loading fails, the compiled
        code fails verification, or the directory cannot be written: the compiled path is
        unavailable and the virtual machine is used.

    Notes
    -----
    Environment failures never propagate; invalid arguments (see :func:`compile_functions`)
    still raise.
    """
    functions = list(functions)
    symbolic = {function.name(): function for function in functions}
    try:
        library = compile_functions(functions, directory, **kw)
    except (CodegenError, OSError) as error:
        warnings.warn(
            f"compiled C path unavailable ({type(error).__name__}: {error}); using CasADi's "
            f"virtual machine for {sorted(symbolic)}",
            RuntimeWarning,
            stacklevel=2,
        )
        return symbolic, None
    if library.path is None:
        return symbolic, library
    return dict(library.functions), library


def batched(
    f: ca.Function,
    population: int,
    parallelization: str = "serial",
    *,
    shared_inputs: Sequence[int] = (),
) -> ca.Function:
    """Map a one-candidate function over the columns of a population matrix.

    CasADi's :meth:`casadi.Function.map` concatenates horizontally: an input of shape
    ``(dim, 1)`` becomes ``(dim, population)`` (column ``k`` = candidate ``k``), and an output of
    shape ``(m, 1)`` becomes ``(m, population)`` (a scalar cost gives a ``1 x population`` row).

    Parameters
    ----------
    f : casadi.Function
        Function whose batched inputs are column vectors.
    population : int
        Number of candidates (columns), at least 1.
    parallelization : {"serial", "thread", "unroll", "openmp"}, default "serial"
        Evaluation strategy of the map.
    shared_inputs : Sequence[int], default ()
        Indices of inputs common to all candidates (e.g. the problem parameters ``p``); they
        keep their shape instead of being repeated (``reduce_in`` of ``Function.map``).

    Returns
    -------
    casadi.Function
        Named ``f.name() + f"_batch{population}"``.

    Raises
    ------
    ValueError
        Bad ``population``, ``parallelization`` or ``shared_inputs``, or a batched input that is
        not a column vector.
    """
    if isinstance(population, bool) or not isinstance(population, int | np.integer):
        raise ValueError(f"population must be an int, got {population!r}")
    if population < 1:
        raise ValueError(f"population must be at least 1, got {population}")
    if parallelization not in _PARALLELIZATIONS:
        raise ValueError(f"parallelization must be one of {_PARALLELIZATIONS}, got {parallelization!r}")
    shared = sorted({int(i) for i in shared_inputs})
    if any(i < 0 or i >= f.n_in() for i in shared):
        raise ValueError(f"shared_inputs {shared} out of range for {f.n_in()} inputs")
    for i in range(f.n_in()):
        if i not in shared and f.size2_in(i) != 1:
            raise ValueError(
                f"input {i} ({f.name_in(i)!r}) of {f.name()!r} has shape {f.size_in(i)}: batched "
                "inputs must be column vectors (or list the input in shared_inputs)"
            )
    name = f"{f.name()}_batch{int(population)}"
    if parallelization == "thread":
        # CasADi 3.8 names a thread map's C worker after the mapped function: two thread maps of
        # one function in one C file clash.  A distinct copy per population avoids it.
        f = _copy(f, f"{f.name()}_cand{int(population)}")
    return f.map(name, parallelization, int(population), shared, [])


def _copy(f: ca.Function, name: str) -> ca.Function:
    """Return a new Function object computing ``f`` (SX: inlined expressions; MX: a call node)."""
    if f.is_a("SXFunction"):
        sx_inputs = f.sx_in()
        return ca.Function(name, sx_inputs, f.call(sx_inputs), f.name_in(), f.name_out())
    mx_inputs = f.mx_in()
    return ca.Function(name, mx_inputs, f.call(mx_inputs), f.name_in(), f.name_out())
