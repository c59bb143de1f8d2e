from jaxplan.cli import main

raise SystemExit(main())
