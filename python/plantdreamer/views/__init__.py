"""The exported views: their cameras (a rig), what lies behind the plant (a background) and
their appearance (jitter), planned per view from the seed (``plan``)."""

from __future__ import annotations

from plantdreamer.views.config import ViewsConfig
from plantdreamer.views.plan import ViewPlan, plan_views

__all__ = ["ViewPlan", "ViewsConfig", "plan_views"]
