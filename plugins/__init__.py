"""Built-in magline plugins (installed as ``magline.plugins``), each loaded via the ``magline`` entry points."""
