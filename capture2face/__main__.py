from capture2face.cli import main

raise SystemExit(main())
