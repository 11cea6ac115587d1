try:
    from clray.cli import run_command
except KeyboardInterrupt:
    # The package itself has loaded (its own import handles Ctrl-C); this is the CLI module.
    import sys

    sys.stderr.write("clray: error: interrupted\n")
    raise SystemExit(130) from None

run_command()
