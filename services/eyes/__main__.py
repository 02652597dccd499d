"""`python -m services.eyes`: the same as `nod eyes`."""

from services.eyes.service import main

raise SystemExit(main())
