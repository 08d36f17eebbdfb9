# SPDX-License-Identifier: Apache-2.0
"""
Monte-Carlo campaigns on Dask distributed (docs/CHARACTERIZE.md): seeded trials, Parquet results, resume.

spec.py: what a campaign is (preset, trials, seed, batch, options; YAML); kind.py: the
interface of a kind of trial; presets/: the kinds (false-id, sky-coverage); engine.py: the
batches on a LocalCluster or a scheduler; results.py: the output directory; bounds.py: the
confidence bound of a counted rate. No ROS.
"""
from __future__ import annotations

from .engine import CampaignRun, run_campaign
from .kind import CampaignKind
from .spec import CampaignSpec, load_campaign_yaml

__all__ = ["CampaignKind", "CampaignRun", "CampaignSpec", "load_campaign_yaml", "run_campaign"]
