"""`python -m services.speaker`: the same as `nod speaker`."""

from services.speaker.service import main

raise SystemExit(main())
