"""Shipped YAML files (palettes, experiment configs), installed as ``claravid.configs``.

Read them through ``claravid.infra.resources``, never by a path relative to the checkout.
"""
