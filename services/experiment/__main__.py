"""`python -m services.experiment`: the same as `nod experiment`."""

from services.experiment.service import main

raise SystemExit(main())
