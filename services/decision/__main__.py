"""`python -m services.decision`: the same as `nod decision`."""

from services.decision.service import main

raise SystemExit(main())
