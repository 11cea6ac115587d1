from clray.cli import main

raise SystemExit(main())
