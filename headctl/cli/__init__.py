"""The `headctl` command line: one entry point (`main`), one module per group of subcommands."""
