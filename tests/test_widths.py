"""Width rules and the cap on widths: a cap that leaves only vanishing Gaussians is refused by key."""

import pytest
import torch

from rbfn.config import MIN_WIDTH_SCALE
from rbfn.widths import check_max_width, paper_widths


def test_a_cap_far_below_the_width_rule_is_refused_naming_the_key():
    z = torch.rand(500, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    with pytest.raises(ValueError, match=r"rbfn\.max_width=1e-30 is not allowed.*use at least"):
        check_max_width(z, 1e-30, 40)


def test_every_cap_that_keeps_the_smallest_useful_width_is_accepted():
    z = torch.rand(500, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    for m in (2, 10, 40, 160):
        centers = z[torch.randperm(500, generator=torch.Generator().manual_seed(m))[:m]]
        smallest_useful = MIN_WIDTH_SCALE * float(paper_widths(centers)[0])
        check_max_width(z, smallest_useful, m)  # the reference is lenient: never refuses these
