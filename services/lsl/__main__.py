"""`python -m services.lsl`: the same as `nod lsl`."""

from services.lsl.service import main

raise SystemExit(main())
