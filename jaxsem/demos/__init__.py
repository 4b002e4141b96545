"""Demo parts run by ``jaxsem demo``; each module has ``run(out_dir, quick) -> str``."""
