"""`python -m services.lab secure …`."""

from services.lab.cli import main

raise SystemExit(main())
