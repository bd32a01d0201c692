from sitl.cli import main

main()
