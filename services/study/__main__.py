"""`python -m services.study`: the same as `nod study`."""

from services.study.cli import main

raise SystemExit(main())
