"""Fixtures: one `csmetro serve` for the session (see support.py), a client, a stage name per
test."""

from __future__ import annotations

import re

import pytest

from csmetro_bluesky import Client
from support import Service


@pytest.fixture(scope="session")
def service(tmp_path_factory):
    s = Service(tmp_path_factory.mktemp("csmetro-serve"))
    yield s
    s.stop()


@pytest.fixture
def client(service) -> Client:
    return service.client(operator="pytest")


@pytest.fixture
def stage(request) -> str:
    """A stage name of this test only: a test never queues behind another's campaign."""
    return "py-" + re.sub(r"[^A-Za-z0-9._-]", "-", request.node.name)[:60]
