"""Residual diagnostics: find what the backlash model lacks, add it, report the error before and after."""
