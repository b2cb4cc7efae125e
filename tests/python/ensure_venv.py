#!/usr/bin/env python3
"""Create (once) the Python virtual environment the system tests use.

Usage: ensure_venv.py VENV_DIR

The environment holds the client libraries of tests/python/requirements.txt.
It is (re)built when its stamp file (a copy of the requirements it was built
from) is missing or differs from requirements.txt, under an exclusive file lock
(VENV_DIR.lock), so several test binaries starting at once build it once and the
others wait for it. Prints the interpreter's path on its last line of stdout.
Exits 1 with pip's output when the packages cannot be installed (for example
when PyPI cannot be reached).
"""

import fcntl
import os
import shutil
import subprocess
import sys
import venv

REQUIREMENTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "requirements.txt")
STAMP = "soundmap-requirements.txt"


def interpreter(venv_dir: str) -> str:
    return os.path.join(venv_dir, "bin", "python")


def up_to_date(venv_dir: str, wanted: str) -> bool:
    try:
        with open(os.path.join(venv_dir, STAMP), encoding="utf-8") as f:
            return f.read() == wanted and os.path.exists(interpreter(venv_dir))
    except FileNotFoundError:
        return False


def build(venv_dir: str, wanted: str) -> None:
    print(f"creating the test virtual environment {venv_dir}", file=sys.stderr)
    if os.path.exists(venv_dir):
        shutil.rmtree(venv_dir)
    venv.EnvBuilder(with_pip=True, clear=True).create(venv_dir)
    cmd = [interpreter(venv_dir), "-m", "pip", "install", "--disable-pip-version-check",
           "--no-input", "-r", REQUIREMENTS]
    print("running: " + " ".join(cmd), file=sys.stderr)
    done = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if done.returncode != 0:
        shutil.rmtree(venv_dir, ignore_errors=True)
        sys.exit(
            f"could not install the test Python packages of {REQUIREMENTS} "
            f"(pip exited {done.returncode}; is PyPI reachable?):\n{done.stdout}"
        )
    with open(os.path.join(venv_dir, STAMP), "w", encoding="utf-8") as f:
        f.write(wanted)
    print(f"installed: {', '.join(requirement_names(wanted))}", file=sys.stderr)


def requirement_names(text: str) -> list:
    return [line.strip() for line in text.splitlines() if line.strip() and not line.startswith("#")]


def main() -> None:
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    venv_dir = os.path.abspath(sys.argv[1])
    with open(REQUIREMENTS, encoding="utf-8") as f:
        wanted = f.read()
    os.makedirs(os.path.dirname(venv_dir), exist_ok=True)
    with open(venv_dir + ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if up_to_date(venv_dir, wanted):
            print(f"the test virtual environment {venv_dir} is up to date", file=sys.stderr)
        else:
            build(venv_dir, wanted)
    print(interpreter(venv_dir))


if __name__ == "__main__":
    main()
