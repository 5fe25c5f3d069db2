"""Tools of the documentation site (not part of the installed toolkit).

- :mod:`docs_tools.cli_reference`: the CLI reference page, generated from ``tpods``'s
  argparse parsers;
- :mod:`docs_tools.hooks`: the MkDocs hook that adds that page to every build;
- :mod:`docs_tools.links`: follows every relative link of a built site;
- :mod:`docs_tools.screenshots`: serves a built site and screenshots it in headless Chromium;
- :mod:`docs_tools.readme_commands`: the README's shell blocks, as commands.

Imported by tests/docs and by mkdocs.yml's hook; nothing in the toolkit imports it.
"""
