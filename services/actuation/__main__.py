"""`python -m services.actuation`: the same as `nod actuation`."""

from services.actuation.service import main

raise SystemExit(main())
