"""`python -m services.sim`: the same as `nod sim`."""

from services.sim.service import main

raise SystemExit(main())
