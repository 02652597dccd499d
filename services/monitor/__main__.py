"""`python -m services.monitor`: the same as `nod monitor`."""

from services.monitor.service import main

raise SystemExit(main())
