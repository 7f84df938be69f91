from tsac_bench.cli import main

main()
