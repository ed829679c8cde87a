"""The ``nrmpc`` command line: one thin module per subcommand over the shared core (evo's pattern)."""
