"""`python -m services.display`: the same as `nod display`."""

from services.display.service import main

raise SystemExit(main())
