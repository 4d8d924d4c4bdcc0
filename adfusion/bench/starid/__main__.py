"""``python -m adfusion.bench.starid [options]``: the benchmark's command line
(:func:`adfusion.bench.starid.driver.main`)."""

import sys

from adfusion.bench.starid.driver import main

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
