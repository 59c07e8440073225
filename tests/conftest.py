import pytest
import torch

from rbfn.robots import load_serial_chain, scara

torch.set_num_threads(1)


@pytest.fixture(scope="session")
def chain():
    return load_serial_chain(scara.URDF_PATH, scara.END_LINK, torch.float64)


@pytest.fixture(scope="session")
def small_data(chain):
    from rbfn.data import make_dataset

    low = torch.tensor([0.0, 0.3, 0.5], dtype=torch.float64)
    high = torch.tensor([2.0, 2.0, 1.5], dtype=torch.float64)
    return make_dataset(chain, low, high, (600, 300, 300), seed=3)
