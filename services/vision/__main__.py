"""`python -m services.vision` = `nod vision`."""

from services.vision.service import main

raise SystemExit(main())
