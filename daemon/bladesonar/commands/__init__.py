"""One module per subcommand: ``register(subparsers)`` adds its options, ``run(args)`` does
the work. Heavy imports happen inside ``run`` so that ``bladesonar --help`` and the daemon
start fast and never pull in optional stages (plots)."""

#: Subcommand modules in the order ``bladesonar --help`` lists them.
COMMANDS = ("simulate", "reference", "analyze", "plot", "report", "run", "room",
            "check_config", "retire")
