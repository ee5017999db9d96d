"""Bluesky/ophyd access to csmetro: a thin client of the ``csmetro serve`` HTTP/JSON API and an
ophyd device that runs a characterisation campaign per ``trigger()``.

    from csmetro_bluesky import Client, CsmetroCampaign
"""

from .client import FINAL_STATES, ApiError, Client
from .device import AxisFigures, CampaignError, CampaignStatus, CsmetroCampaign, FigureSignal
from .figures import AXIS_FIGURES, CAMPAIGN_FIGURES, Figure

__version__ = "0.1.0"

__all__ = [
    "AXIS_FIGURES",
    "ApiError",
    "AxisFigures",
    "CAMPAIGN_FIGURES",
    "CampaignError",
    "CampaignStatus",
    "Client",
    "CsmetroCampaign",
    "FINAL_STATES",
    "Figure",
    "FigureSignal",
]
