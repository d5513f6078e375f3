from vts_hw.cli import main

main()
