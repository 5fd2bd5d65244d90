"""The ``monodock`` command line: one module per command; argparse lives only here."""
