"""``python -m capture2face``."""

import os
import sys

try:
    from capture2face.cli import main
except KeyboardInterrupt:  # Ctrl-C while the libraries load, before the command's own handler exists
    print("capture2face: interrupted", file=sys.stderr, flush=True)
    os._exit(130)  # not SystemExit: after an interrupted import CPython would end by SIGINT (errors.exit_interrupted)

raise SystemExit(main())
