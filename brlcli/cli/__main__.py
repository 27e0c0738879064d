"""`python -m brlcli.cli`: the `brl` command line."""

from brlcli.cli import main

main()
