from ecatcfg.cli import main

raise SystemExit(main())
