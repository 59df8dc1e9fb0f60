"""``python -m capture2face``."""

from capture2face.entry import main

raise SystemExit(main())
