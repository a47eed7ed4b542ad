from wamctl.cli import main

main()
