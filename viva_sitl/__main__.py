from viva_sitl.cli import main

raise SystemExit(main())
