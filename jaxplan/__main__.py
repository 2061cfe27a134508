"""`python -m jaxplan ...` is the `jaxplan` command."""

from jaxplan.cli import main

raise SystemExit(main())
