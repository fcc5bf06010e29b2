from blurtrack.cli import main; import sys; sys.exit(main())
