"""`python -m vacc`: the same as the `vacc` console script."""

from vacc.cli import main

if __name__ == "__main__":
    main(prog_name="vacc")
