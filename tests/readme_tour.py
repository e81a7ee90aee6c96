"""The README's tour, top to bottom as written, on a fresh clone (not in CI: minutes).

    .venv/bin/python tests/readme_tour.py [--keep] [--venv DIR]

Clones this repository's HEAD into a temporary directory, makes its environment there
(``make install``, as a user would after ``git clone``; ``--venv DIR`` uses an existing
environment's ``flatcli`` instead, to save the install), saves the tour's files of one's own
(the ```toml blocks above its commands) in the clone, then runs every line of the tour's
```sh block there in order with the clone's ``.venv/bin`` first on PATH, and the Python block
after it. ``TRIAL`` is the one placeholder: the first id of the sweep's trials.parquet. Every
command must end with its documented exit status (``flatcli design``: its verdict's, 0, 1 or
3; everything else 0). Prints each command, its status and time; exits 1 at the first that
fails, naming it.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Exit statuses a command may document besides 0 (docs/commands.md).
ALLOWED = {"design": {0, 1, 3}}


def tour(readme: str) -> tuple[dict[str, str], list[str], str]:
    """The tour's files of one's own (name -> text), its shell lines (comments dropped) and
    its Python block, as the README writes them."""
    section = readme.split("## A tour")[1].split("\n## ")[0]
    head, _, rest = section.partition("```sh\n")
    files = {}
    for block in head.split("```toml\n")[1:]:
        body = block.split("```", 1)[0]
        files[body.splitlines()[0].removeprefix("# ").split(":")[0].strip()] = body
    shell, _, after = rest.partition("```")
    lines = []
    for line in shell.splitlines():
        command = re.sub(r"\s+#.*$", "", line).strip()  # the comment after the command
        if command:
            lines.append(command)
    python = after.split("```python\n", 1)[1].split("```", 1)[0] if "```python" in after else ""
    return files, lines, python


def run(command: str, cwd: Path, env: dict[str, str]) -> tuple[int, float, str]:
    started = time.perf_counter()
    done = subprocess.run(command, shell=True, cwd=cwd, env=env, capture_output=True, text=True)
    return done.returncode, time.perf_counter() - started, done.stdout + done.stderr


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", action="store_true", help="keep the clone and its runs")
    parser.add_argument("--venv", type=Path, help="an environment with flatcli installed")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="flatcli-tour-"))
    clone = work / "flatcli"
    try:
        subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
        env = dict(os.environ)
        env.pop("PYTHONPATH", None)
        if args.venv is None:
            code, seconds, out = run("make install", clone, env)
            print(f"make install: exit {code}, {seconds:.0f} s", flush=True)
            if code:
                print(out[-3000:])
                return 1
            bin_dir = clone / ".venv" / "bin"
        else:
            bin_dir = args.venv.resolve() / "bin"
        env["PATH"] = f"{bin_dir}{os.pathsep}{env['PATH']}"
        files, commands, python = tour((clone / "README.md").read_text())
        for name, text in files.items():
            (clone / name).write_text(text)
        print(f"saved {', '.join(files)}", flush=True)
        for command in commands:
            if "TRIAL" in command:
                trial = subprocess.run(
                    [str(bin_dir / "python"), "-c", "import pyarrow.parquet as pq; print(pq."
                     "read_table('runs/paper_montecarlo/sweep/trials.parquet', columns=['trial'])"
                     ".column(0)[0])"], cwd=clone, env=env, capture_output=True, text=True,
                    check=True).stdout.strip()
                command = command.replace("TRIAL", trial)
            code, seconds, out = run(command, clone, env)
            word = command.split()[1] if len(command.split()) > 1 else ""
            ok = code in ALLOWED.get(word, {0})
            print(f"{'ok  ' if ok else 'FAIL'} exit {code} {seconds:6.1f} s  {command}",
                  flush=True)
            if not ok:
                print(out[-3000:])
                return 1
        if python:
            code, seconds, out = run(f"{bin_dir / 'python'} -c {shlex_quote(python)}", clone,
                                     env)
            print(f"{'ok  ' if code == 0 else 'FAIL'} exit {code} {seconds:6.1f} s  the Python "
                  "block", flush=True)
            if code:
                print(out[-3000:])
                return 1
        print(f"the tour ran top to bottom ({len(commands)} commands and the Python block)")
        return 0
    finally:
        if args.keep:
            print(f"kept {clone}")
        else:
            shutil.rmtree(work, ignore_errors=True)


def shlex_quote(text: str) -> str:
    import shlex

    return shlex.quote(text)


if __name__ == "__main__":
    sys.exit(main())
