"""tectum's built-in plugins, one module (or package) per family.

Each registers its components through the ``tectum_register_*`` hooks and is
listed in the ``tectum`` entry-point group of ``pyproject.toml``, exactly as
a third-party plugin would be.
"""
