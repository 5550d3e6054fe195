"""Build an example C program next to the generated library and run it from another folder."""

from __future__ import annotations

import subprocess
from pathlib import Path

from uuv_ocp import codegen


def build_and_run(source: Path, libraries: list[Path], include: Path, argument: Path, tmp_path: Path) -> str:
    """Compile ``source`` beside ``libraries`` (rpath ``$ORIGIN``), run it from elsewhere; its stdout.

    Every function it calls must be declared in the generated header
    (``-Werror=implicit-function-declaration``), and running it from a folder other than the
    library's checks that the rpath does not depend on the working directory.
    """
    program = include / source.stem
    command = [
        codegen.find_c_compiler(),
        "-Werror=implicit-function-declaration",
        str(source),
        f"-I{include}",
        *(str(library) for library in libraries),
        "-Wl,-rpath,$ORIGIN",
        "-lm",
        "-o",
        str(program),
    ]
    subprocess.run(command, check=True, capture_output=True, text=True)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir(exist_ok=True)
    return subprocess.run(
        [str(program), str(argument)], check=True, capture_output=True, text=True, cwd=elsewhere
    ).stdout
