from harborsight.cli import main

main()
