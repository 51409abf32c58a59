"""Evaluation: sliding-window inference, confusion matrices, mIoU per complexity bin, reports.

Not built yet: see the project's issues.
"""
