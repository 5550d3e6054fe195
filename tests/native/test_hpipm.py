"""HPIPM and BLASFEO built for this CPU (uuv_ocp.native.hpipm): target, manifest checks, selection, result."""

import json
import os
import re
import shutil
import stat
import warnings

import numpy as np
import pytest

import uuv_ocp as uo
from tests.conftest import needs_compiler
from uuv_ocp.native import hpipm
from uuv_ocp.native.compile import find_c_compiler


@pytest.mark.parametrize(
    "flags, target",
    [
        ({"sse2", "pni", "avx", "avx2", "fma"}, "X64_INTEL_HASWELL"),
        ({"sse2", "pni", "avx", "avx2"}, "X64_INTEL_SANDY_BRIDGE"),  # AVX2 without FMA: no Haswell kernels
        ({"sse2", "pni"}, "X64_INTEL_CORE"),
        ({"sse2"}, "GENERIC"),
    ],
)
def test_cpu_target_takes_the_best_kernels_the_flags_allow(flags, target):
    assert hpipm.cpu_target(flags) == target


KEY = "0123456789abcdef"


def _fake_build(root, key=KEY, files=None, directory=None):
    """Write a build folder with a manifest and the pointer to it, as hpipm.build does.

    ``directory``: where the build goes (default ``root/hpipm/key``, as hpipm.build puts it).
    """
    directory = directory or root / "hpipm" / key
    files = files or {"lib/libhpipm.a": b"hpipm", "lib/libblasfeo.a": b"blasfeo", "include/hpipm/x.h": b"h"}
    for name, content in files.items():
        (directory / name).parent.mkdir(parents=True, exist_ok=True)
        (directory / name).write_bytes(content)
    manifest = {
        "target": "X64_INTEL_HASWELL",
        "files": {name: hpipm._file_digest(directory / name) for name in files},
    }
    (directory / "manifest.json").write_text(json.dumps(manifest))
    pointer = {"key": key, "manifest_sha256": hpipm._file_digest(directory / "manifest.json")}
    (root / "hpipm").mkdir(parents=True, exist_ok=True)
    (root / "hpipm" / "native.json").write_text(json.dumps(pointer))
    for path in [root, *root.rglob("*"), *directory.parent.rglob("*")]:
        path.chmod(0o700 if path.is_dir() else 0o600)  # as hpipm.build writes them
    return directory


def test_installed_checks_every_file_against_the_manifest(tmp_path):
    assert hpipm.installed(tmp_path) is None  # nothing built: the wheel's libraries, silently
    directory = _fake_build(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        build = hpipm.installed(tmp_path)
    assert build is not None and build.directory == directory and build.target == "X64_INTEL_HASWELL"
    flags = build.link_flags()
    assert str(directory / "lib" / "libhpipm.a") in flags and "-Wl,--exclude-libs,ALL" in flags
    (directory / "lib" / "libblasfeo.a").write_bytes(b"blasfeO")  # one byte changed
    with pytest.warns(RuntimeWarning, match="libblasfeo.a does not match"):
        assert hpipm.installed(tmp_path) is None


def test_installed_refuses_a_manifest_that_is_not_the_recorded_one(tmp_path):
    directory = _fake_build(tmp_path)
    manifest = json.loads((directory / "manifest.json").read_text())
    manifest["files"].pop("lib/libblasfeo.a")  # a manifest edited to skip a changed library
    (directory / "manifest.json").write_text(json.dumps(manifest))
    with pytest.warns(RuntimeWarning, match="manifest.json does not match"):
        assert hpipm.installed(tmp_path) is None


def test_selection_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path))
    monkeypatch.setenv(hpipm.HPIPM_ENV, "native")
    with pytest.raises(hpipm.NativeHpipmError, match="uuv-ocp hpipm build"):
        hpipm.selected()
    _fake_build(tmp_path)
    assert hpipm.selected() is not None
    monkeypatch.setenv(hpipm.HPIPM_ENV, "wheel")
    assert hpipm.selected() is None
    monkeypatch.setenv(hpipm.HPIPM_ENV, "fast")
    with pytest.raises(ValueError, match="UUV_OCP_HPIPM must be one of"):
        hpipm.selected()


def test_build_refuses_bad_arguments_before_any_work(tmp_path):
    with pytest.raises(ValueError, match="target must be 'auto' or one of"):
        hpipm.build(target="PENTIUM", cache=tmp_path)
    with pytest.raises(ValueError, match="source must hold blasfeo/ and hpipm/"):
        hpipm.build(source=tmp_path, cache=tmp_path)
    with pytest.raises(ValueError, match="jobs must be an int >= 1"):
        hpipm.build(jobs=0, cache=tmp_path)
    assert not (tmp_path / "hpipm").exists()


def test_the_old_partial_condensing_api_is_read_from_the_header(tmp_path):
    old = "void d_part_cond_qp_expand_sol(struct qp *a, struct qp *b, struct s *c, struct s *d, A *e, W *f);"
    new = "void d_part_cond_qp_expand_sol(struct qp *a, struct s *c, struct s *d, A *e, W *f);"
    for text, reads_qp in ((old, True), (new, False)):
        (tmp_path / "hpipm_d_part_cond.h").write_text(text)
        assert hpipm.old_partial_condensing(tmp_path) is reads_qp


@needs_compiler
@pytest.mark.slow
def test_the_native_step_equals_the_wheel_step(s2_problem, monkeypatch):
    """The C step linked to BLASFEO's AVX2 kernels solves the RTI QP as the wheel's generic copy.

    Builds the native libraries from the pinned sdist when none is installed (about a minute,
    then cached), then one RTI iteration of s2, plain and partially condensed, on both.
    """
    if hpipm.installed() is None:
        hpipm.build(log=lambda line: None)
    from uuv_ocp.solvers.rti import RtiSolver

    find_c_compiler()
    state = s2_problem.reference.evaluate([3.0])[0] + np.array([0.1, -0.1, 0.02, 0.0, 0.0, 0.0])
    p = s2_problem.parameters(state, 3.0, np.zeros(3))
    warm = uo.solve(s2_problem, "ipopt", x0=state, t0=3.0).iterate.shift()
    # tight QP tolerances (as tests/solvers/test_rti.py's 1e-8 comparisons): at HPIPM's defaults the two
    # kernels' rounding stops the interior-point iterations at points 4e-8 apart, both within them
    tight = {"mode": "robust", "iter_max": 200, **{f"tol_{k}": 1e-11 for k in ("stat", "eq", "ineq", "comp")}}
    for qp_options in (tight, {**tight, "cond_horizon": 5}):
        results, libraries = {}, set()
        for choice in ("wheel", "native"):
            monkeypatch.setenv(hpipm.HPIPM_ENV, choice)  # read when the step is built, at its first solve
            backend = RtiSolver(s2_problem, {"qpsol": "hpipm-ocp", "qpsol_options": qp_options})
            result = backend.solve(p, warm)
            assert result.success, result.status
            results[choice] = result
            step = backend.ocp_step(result.iterate.variant, result.details["still_water"])
            libraries.add(step.library._name)
        assert len(libraries) == 2  # two builds, not one cached library twice
        wheel, native = results["wheel"], results["native"]
        assert np.max(np.abs(native.iterate.primal - wheel.iterate.primal)) <= 1e-8
        # multipliers (up to 1e4 here) of nearly active rows are fixed only to the IPM's tolerances
        scale = max(1.0, float(np.max(np.abs(wheel.iterate.lam_g))))
        assert np.max(np.abs(native.iterate.lam_g - wheel.iterate.lam_g)) <= 1e-5 * scale


def test_cli_reports_the_build_in_use_and_refuses_a_bad_target(tmp_path, monkeypatch, capsys):
    from uuv_ocp.cli import main

    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path))
    assert main(["hpipm", "status"]) == 0
    assert "none" in capsys.readouterr().out
    directory = _fake_build(tmp_path)
    assert main(["hpipm", "status"]) == 0
    assert str(directory) in capsys.readouterr().out
    assert main(["hpipm", "build", "--target", "PENTIUM"]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("error: target must be") and "\n" not in error


# -- nothing of the cache's hpipm/ folder is used unchecked (issue 31) --------------------------


@pytest.mark.parametrize("kind", ["absolute", "escaping", "short", "not a string"])
def test_a_native_json_naming_a_path_is_refused(tmp_path, monkeypatch, capsys, kind):
    """An absolute or ../ key pointed `hpipm status` and the next C step at anybody's build."""
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    theirs = _fake_build(tmp_path / "other", directory=tmp_path / "theirs" / KEY)  # complete, intact
    key = {"absolute": str(theirs), "escaping": f"../../theirs/{KEY}", "short": "abc", "not a string": 12}[
        kind
    ]
    pointer = json.loads((tmp_path / "other" / "hpipm" / "native.json").read_text())
    (cache / "hpipm").mkdir(mode=0o700)
    (cache / "hpipm" / "native.json").write_text(json.dumps({**pointer, "key": key}))
    (cache / "hpipm" / "native.json").chmod(0o600)

    with pytest.warns(RuntimeWarning, match="key must be 16 hex digits"):
        assert hpipm.installed(cache) is None
    with pytest.raises(hpipm.NativeHpipmError, match="key must be 16 hex digits"):
        hpipm.installed(cache, strict=True)

    from uuv_ocp.cli import main
    from uuv_ocp.codegen import hpipm_link_flags

    monkeypatch.setenv("UUV_OCP_CACHE", str(cache))
    assert main(["hpipm", "status"]) == 1
    out = capsys.readouterr().out
    assert "refused" in out and str(theirs) not in out.replace(repr(key), "")
    monkeypatch.setenv(hpipm.HPIPM_ENV, "auto")
    with pytest.warns(RuntimeWarning, match="key must be"):
        flags = hpipm_link_flags()  # the C step's flags: the wheel's, nothing of theirs
    assert not any(str(theirs) in flag for flag in flags) and "-lhpipm" in flags
    monkeypatch.setenv(hpipm.HPIPM_ENV, "native")
    with pytest.raises(ValueError, match="UUV_OCP_HPIPM=native but the native build is refused"):
        hpipm_link_flags()


def _group_writable(path):
    path.chmod(path.stat().st_mode | 0o020)


@pytest.mark.parametrize(
    "damage, reason",
    [
        (lambda d: _group_writable(d.parent), "writable by its group or by others"),  # hpipm/
        (lambda d: _group_writable(d.parent.parent), "writable by its group or by others"),  # the cache
        (lambda d: _group_writable(d), "writable by its group or by others"),  # the build
        (lambda d: _group_writable(d / "include" / "hpipm"), "writable by its group or by others"),
        (lambda d: _group_writable(d / "lib" / "libhpipm.a"), "writable by its group or by others"),
        (lambda d: _group_writable(d / "manifest.json"), "writable by its group or by others"),
        (lambda d: _group_writable(d.parent / "native.json"), "writable by its group or by others"),
        (lambda d: (d / "include" / "hpipm" / "stdio.h").write_text("/* planted */"), "not listed"),
        (lambda d: _symlink_over(d / "lib" / "libhpipm.a"), "symbolic link"),
        (lambda d: _symlink_over(d.parent / "native.json"), "symbolic link"),
        (lambda d: _symlink_over(d / "include" / "hpipm", folder=True), "symbolic link"),
        (lambda d: os.mkfifo(d / "include" / "hpipm" / "y.h"), "not a regular file"),
    ],
    ids=[
        "hpipm-folder",
        "cache-folder",
        "build-folder",
        "include-folder",
        "library",
        "manifest",
        "native.json",
        "planted-header",
        "symlinked-library",
        "symlinked-native.json",
        "symlinked-folder",
        "fifo",
    ],
)
def test_every_folder_and_file_of_the_build_is_checked(tmp_path, damage, reason):
    """The hpipm/ folder was not checked at all: a group member could swap headers or libraries."""
    directory = _fake_build(tmp_path / "cache")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert hpipm.installed(tmp_path / "cache") is not None
    damage(directory)
    with pytest.warns(RuntimeWarning, match=reason):
        assert hpipm.installed(tmp_path / "cache") is None


def _symlink_over(path, folder=False):
    """Replace ``path`` by a symbolic link to an identical copy (same bytes, same digests)."""
    copy = path.with_name(path.name + ".real")
    os.rename(path, copy)
    path.symlink_to(copy, target_is_directory=folder)


FAKE_MAKEFILE = """static_library:
\tmkdir -p lib include
\tprintf '{name}' > lib/lib{name}.a
\tprintf '/* {name} */' > include/{name}.h
"""


@pytest.mark.skipif(shutil.which("make") is None, reason="no make")
def test_build_writes_private_files_whatever_the_umask(tmp_path, monkeypatch):
    """With umask 002 make's output and the copies came out group-writable: now 0600 / 0700."""
    find_c_compiler_or_skip()
    source = tmp_path / "source"
    for name in ("blasfeo", "hpipm"):
        (source / name).mkdir(parents=True)
        (source / name / "Makefile").write_text(FAKE_MAKEFILE.format(name=name))
    previous = os.umask(0o002)
    try:
        build = hpipm.build(source, "GENERIC", cache=tmp_path / "cache", log=lambda line: None)
    finally:
        os.umask(previous)
    cache = tmp_path / "cache"
    for path in [cache, *cache.rglob("*")]:
        expected = 0o700 if path.is_dir() else 0o600
        assert stat.S_IMODE(path.stat().st_mode) == expected, path
    assert hpipm.installed(cache, strict=True) == build
    assert (build.directory / "lib" / "libhpipm.a").read_text() == "hpipm"


def find_c_compiler_or_skip():
    try:
        find_c_compiler()
    except Exception as error:  # CompilerNotFoundError
        pytest.skip(str(error))


# -- a bad UUV_OCP_HPIPM is refused when the controller is built --------------------------------


@pytest.mark.parametrize(
    "value, qpsol, message",
    [
        ("bogus", "hpipm-ocp", "UUV_OCP_HPIPM must be one of auto, wheel, native, got 'bogus'"),
        ("bogus", "hpipm", "UUV_OCP_HPIPM must be one of"),
        ("native", "hpipm-ocp", "UUV_OCP_HPIPM=native but no native HPIPM is built in"),
    ],
)
def test_bad_hpipm_setting_is_refused_when_the_controller_is_built(
    tmp_path, monkeypatch, value, qpsol, message
):
    """29 of 30 closed-loop steps used to fail into the fallback, and the run returned normally."""
    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path / "empty"))
    monkeypatch.setenv(hpipm.HPIPM_ENV, value)
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=4)
    with pytest.raises(ValueError, match=message):
        uo.NMPC(problem, "sqp-rti", options={"qpsol": qpsol})


def test_native_setting_with_a_build_is_accepted_up_front(tmp_path, monkeypatch):
    _fake_build(tmp_path)
    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path))
    monkeypatch.setenv(hpipm.HPIPM_ENV, " Native ")
    hpipm.check_choice()
    monkeypatch.setenv(hpipm.HPIPM_ENV, "native")
    (tmp_path / "hpipm" / KEY / "lib" / "libhpipm.a").write_bytes(b"changed")
    with pytest.raises(hpipm.HpipmChoiceError, match="does not match its SHA-256"):
        hpipm.check_choice()
    hpipm.check_choice(native_needed=False)  # the conic path does not link it: only the value counts


def _stand_in_builder(calls: list, fail: bool = False):
    """Return a :func:`hpipm.build` stand-in that logs the real stages, then returns a build or fails."""

    def builder(cache=None, log=print):
        calls.append(cache)
        log("fetching rockit-meco==0.2.8 (source distribution, BLASFEO and HPIPM inside) with pip")
        if fail:
            raise hpipm.NativeHpipmError("pip download rockit-meco==0.2.8 failed: no network")
        log("building BLASFEO (TARGET=X64_INTEL_HASWELL) with cc")
        log("building HPIPM (TARGET=AVX)")
        log("installed in /somewhere")
        return hpipm.NativeHpipm(hpipm.Path("/somewhere"), "X64_INTEL_HASWELL", "0" * 64)

    return builder


def test_a_first_need_builds_the_native_hpipm_once_with_a_message_and_a_bar(tmp_path, monkeypatch, capsys):
    """``auto`` with no build: one line says what is built, a bar follows the stages; no warning."""
    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path))
    monkeypatch.setenv(hpipm.HPIPM_ENV, "auto")
    monkeypatch.delenv(hpipm.HPIPM_BUILD_ENV, raising=False)
    monkeypatch.setattr(hpipm, "cpu_target", lambda flags=None: "X64_INTEL_HASWELL")
    calls: list = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        native = hpipm.for_c_step(builder=_stand_in_builder(calls))
    assert native is not None and native.target == "X64_INTEL_HASWELL" and len(calls) == 1
    err = capsys.readouterr().err
    lines = [line for line in err.split("\n") if line.strip()]
    assert lines[0].startswith("uuv_ocp: building HPIPM and BLASFEO for this CPU (X64_INTEL_HASWELL), once")
    assert "UUV_OCP_HPIPM_BUILD=never skips this" in lines[0]
    assert "[####] 4/4 installed" in err and len(lines) == 2  # the message, then one bar line


@pytest.mark.parametrize("case", ["never", "generic cpu", "wheel", "failed build", "refused build"])
def test_a_first_need_keeps_the_wheel_and_says_why(tmp_path, monkeypatch, capsys, case):
    """No build where it is switched off, pointless or failed before: one warning names why.

    ``UUV_OCP_HPIPM=wheel`` asks for the wheel: no build and no warning.  A failed build is
    recorded in the cache and not retried by the next first need (the warning says how to).
    """
    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path))
    monkeypatch.setenv(hpipm.HPIPM_ENV, "wheel" if case == "wheel" else "auto")
    monkeypatch.setenv(hpipm.HPIPM_BUILD_ENV, "never" if case == "never" else "auto")
    cpu = "GENERIC" if case == "generic cpu" else "X64_INTEL_HASWELL"
    monkeypatch.setattr(hpipm, "cpu_target", lambda flags=None: cpu)
    calls: list = []
    builder = _stand_in_builder(calls, fail=case == "failed build")
    if case == "refused build":  # a native.json naming no intact build: refused, never rebuilt unasked
        (tmp_path / "hpipm").mkdir(mode=0o700)
        pointer = {"key": "0" * 16, "manifest_sha256": "0" * 64}
        (tmp_path / "hpipm" / "native.json").write_text(json.dumps(pointer))
        (tmp_path / "hpipm" / "native.json").chmod(0o600)
    expected = {
        "refused build": "the native build recorded in the cache is refused",
        "never": "UUV_OCP_HPIPM_BUILD=never",
        "generic cpu": "no BLASFEO kernels better than the wheel's",
        "failed build": "the native build failed .NativeHpipmError: pip download",
    }
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert hpipm.for_c_step(builder=builder) is None
    messages = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    if case == "refused build":  # installed()'s own warning first, naming the refused file
        messages = [m for m in messages if "links the CasADi wheel's HPIPM" in m]
    if case == "wheel":
        assert messages == [] and calls == []
        return
    assert len(messages) == 1 and "links the CasADi wheel's HPIPM" in messages[0]
    assert re.search(expected[case], messages[0]), messages[0]
    assert len(calls) == (case == "failed build")
    if case == "failed build":
        with warnings.catch_warnings(record=True) as again:
            warnings.simplefilter("always")
            assert hpipm.for_c_step(builder=builder) is None
        assert len(calls) == 1  # not retried
        message = str(again[0].message)
        assert "its build failed before" in message and hpipm.FAILED_MARKER in message
    monkeypatch.setenv(hpipm.HPIPM_BUILD_ENV, "sometimes")
    with pytest.raises(ValueError, match="UUV_OCP_HPIPM_BUILD must be one of auto, never"):
        hpipm.build_policy()
