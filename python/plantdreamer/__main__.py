from plantdreamer.cli import main

main()
