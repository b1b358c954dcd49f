"""The development suite: every weight set over sampling seeds 0-4 on York Urban (both ground-truth horizons), CSV
manifests and renders, as mean and range, with seconds per image and the real-photo mean used to choose defaults.

Usage::

    python benchmarks/devsuite.py --yud ../shared/data/YorkUrbanDB \\
        --manifest ../shared/data/EurasianCities/manifest.csv --renders /tmp/render_test \\
        --weights none --weights zsnet --weights fsnet --weights full [--seeds 0,1,2,3,4] [--json suite.json]

The same as ``python -m ngp_kornia.evaluation`` (:mod:`ngp_kornia.evaluation.suite`); ``--help`` lists the options.
"""

from ngp_kornia.evaluation.suite import main

if __name__ == "__main__":
    raise SystemExit(main())
