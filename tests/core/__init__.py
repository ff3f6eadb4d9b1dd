"""Tests of the package's bottom layer: schema, geometry, spaces, augmentations, dataset reads, locks."""
