"""Helpers the tests share: plain functions and session fixtures, imported from here (never from
another folder's conftest or test module)."""
