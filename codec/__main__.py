"""`python -m codec`: the `atm` command line tool (codec.cli)."""

from codec.cli.main import main

raise SystemExit(main())
