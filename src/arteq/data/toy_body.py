"""Moved to :mod:`arteq.body.toy` (the toy body is a ``BodyModel``); kept until ``data/datamodule.py``
builds bodies with :func:`arteq.body.create_body`."""

from arteq.body.toy import ToyBody

__all__ = ["ToyBody"]
