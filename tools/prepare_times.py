"""How long each character takes to prepare from an empty cache, and to read back after.

    python tools/prepare_times.py CHARACTER [CHARACTER ...]

Each character (.glb, .gltf, .vrm) is prepared in a child process with its own empty
``CAPTURE2FACE_CACHE`` (import, landmark cast, baked maps: ``character/prepared.py``), then
read back from that cache in a second child process, as a rerun or a batch worker reads it.
The times are wall-clock seconds of ``load_character`` alone (not the interpreter's start),
so they depend on the machine's load: say the load beside them.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

TIMED = ("import sys, time\n"
         "from capture2face.character.load import load_character\n"
         "start = time.perf_counter(); load_character(sys.argv[1]); print(time.perf_counter() - start)\n")


def timed_load(character: Path, cache: Path) -> float:
    """Seconds ``load_character(character)`` takes in a fresh process using ``cache``."""
    env = dict(os.environ, CAPTURE2FACE_CACHE=os.fspath(cache), GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")
    done = subprocess.run([sys.executable, "-c", TIMED, os.fspath(character)], capture_output=True, text=True,
                          env=env, check=False)
    if done.returncode != 0:
        raise SystemExit(f"{character}: {done.stderr.strip().splitlines()[-1] if done.stderr.strip() else 'failed'}")
    return float(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("characters", nargs="+", type=Path, metavar="CHARACTER")
    args = parser.parse_args(argv)
    print("| character | prepare (s) | read back (s) |\n|---|---|---|")
    for character in args.characters:
        with tempfile.TemporaryDirectory(prefix="c2f-prepare-") as cache:
            first, again = timed_load(character, Path(cache)), timed_load(character, Path(cache))
        print(f"| {character.name} | {first:.1f} | {again:.2f} |", flush=True)
    print(f"load average while measuring: {os.getloadavg()[0]:.1f} ({os.cpu_count()} cores)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
