from sensaov_cli.cli import main

main(prog_name="sensaov")
