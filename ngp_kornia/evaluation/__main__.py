"""``python -m ngp_kornia.evaluation``: the development suite (see :mod:`ngp_kornia.evaluation.suite`)."""

from ngp_kornia.evaluation.suite import main

if __name__ == "__main__":
    raise SystemExit(main())
