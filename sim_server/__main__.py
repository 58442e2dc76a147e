"""`python -m sim_server`: the standalone simulator process."""

from sim_server.cli import serve

if __name__ == "__main__":
    serve(prog_name="python -m sim_server")
