"""`python -m brlcli`: the brl command line."""

from brlcli.cli import main

main()
