import pytest


def pytest_addoption(parser):
    parser.addoption("--full", action="store_true", default=False,
                     help="also run the slow full refinement studies")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--full"):
        return
    skip = pytest.mark.skip(reason="slow study: run with --full")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
