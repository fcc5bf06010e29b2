"""``python -m blurtrack``: the blurtrack CLI (which ends without the interpreter's teardown,
:func:`blurtrack.cli.exit_program`)."""

from blurtrack.cli import exit_program, main

exit_program(main())
