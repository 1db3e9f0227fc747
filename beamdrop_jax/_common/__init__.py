"""Shared plumbing of the package: input checks and flags, how programs compile, fast trigonometry, plain-text reports. Imports nothing else of the package."""
