from fpv_station.server.cli import main

raise SystemExit(main())
