"""The documentation: the README, the site, its generated pages."""
