import sys, json
from vacc.bench import flood_rtt
addr = None if len(sys.argv) < 2 else ("127.0.0.1", int(sys.argv[1]))
print(json.dumps(flood_rtt(samples=200, addr=addr)))
