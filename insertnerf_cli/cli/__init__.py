"""The `insertnerf` command line: the console entry point (main.py), the command group (group.py) and one
module per command (commands/). Each command parses its options and calls a library function."""
