"""The theta study of the block-friction case at the documented size (level 3 against a
level-5 reference): writes docs/theta_study.png and benchmarks/results/theta_study.json.
`nitsche run block-friction --set theta_study=true --level L` (and the paper index) make
the same figure at any level.

    python benchmarks/theta_study.py
"""
import os

from nitsche.cases.block_friction import plot_theta_study, theta_study
from nitsche.io import write_json


def main(level=3, fine=5):
    here = os.path.dirname(os.path.abspath(__file__))
    rows = theta_study(level, fine)
    write_json(os.path.join(here, "results", "theta_study.json"),
               dict(level=level, reference_level=fine, rows=rows))
    plot_theta_study(rows, os.path.join(here, "..", "docs", "theta_study.png"))


if __name__ == "__main__":
    main()
