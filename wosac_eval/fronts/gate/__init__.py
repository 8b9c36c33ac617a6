"""Regression gate and reports: compare two scoring runs, render an HTML report."""
