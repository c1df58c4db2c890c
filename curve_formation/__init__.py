"""curve_formation: formation control of nonholonomic robots along parametric curves."""


def version():
    """The installed package's version (setup.py, package.xml), or 'unknown' if not installed."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed
    try:
        return installed('curve_formation')
    except PackageNotFoundError:
        return 'unknown'
