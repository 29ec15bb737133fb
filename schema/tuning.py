"""Every tuning constant of the simulator, with its unit and the measurement that chose it.

A tuning constant changes how fast something is done (or how long a process waits or holds), never what is
decided while every process keeps up: journals are the same whatever their values. The waits (the last section)
also bound what a crashed, hung or cut-off peer costs, so they decide when such a peer counts as gone. Not here: the
wire contract's limits (`MAX_COORD`, `MAX_PAYLOAD`...), the bounds on what a display keeps (entities/web/) and the
world generator's parameters (world/grid.py), which decide the world. It is in `schema`, which imports none of
our packages: all can read it.

Measurements: 2026-11-23, AMD EPYC, 2 cores shared with other work, Python 3.11.7, numpy 2.4; each "a vs b" is
the best of several runs of a short script (see docs/performance.md).
"""

#: Rows up to which a table is checked row by row in Python (`Table._why_few`), not by numpy columns
#: (`Table._why_columns`). Valid rows, row by row vs numpy: a STATUS 1 row 10 vs 34 µs, 8: 11 vs 21, 16: 18 vs 21,
#: 32: 36 vs 23; a MOVES's steps 1: 4 vs 18, 8: 7 vs 19, 16: 11 vs 23, 32: 19 vs 26; a WELCOME's starts 1: 4 vs 8, 8:
#: 8 vs 11, 16: 12 vs 11, 32: 20 vs 11. Warm, which understates it: cold, on a thread just woken, the numpy checks
#: cost a one-drone game's turn 5 to 20 % of its time (`dronesim bench perf`, on and off alternated).
CHECK_FEW_ROWS = 8

#: Turns (GCS phases) ahead a ground station's DONE may come and be held by the coordinator. Not measured: a bound
#: on what a station may make the coordinator hold, twice `ANSWER_AHEAD`.
AHEAD_MAX = 16

#: Rows (moves of a MOVES, targets of a DONE) up to which the engine takes a batch row by row, through an NPS's or
#: a TGT's checks, not in array operations. The `receive` of a MOVES that closes the drones' phase, row by row vs
#: arrays: 2 moves 171 vs 184 µs, 8: 186 vs 194, 16: 199 vs 194, 32: 277 vs 225.
FEW_ROWS = 8

#: Drones up to which the engine reads a few rows of its fleet's columns by reading the whole columns into lists
#: (`Fleet.column`), not by a selection: 1 row of 1 drone's cells 0.1 vs 1.3 µs, 16 of 16: 2.2 vs 2.8, 16 of 1000:
#: 313 vs 2.1 (`ndarray.tolist` vs `ndarray.take(...).tolist`).
SMALL_FLEET = 128

#: Alive drones up to which the engine plays a turn over Python's lists (`Judge._few`, coordinator/judge.py: the
#: moves, the observer's rules drone by drone only when someone may die, the notes, misses and journal), not in array
#: operations (`Judge._arrays`). A whole turn (`Engine.play`, every drone moving) on 64x64x16, lists vs arrays (CPU
#: time, best of 7, load 6): 1 drone 10 vs 64 µs, 8: 16 vs 83, 16: 25 vs 88, 32: 46 vs 93, 48: 59 vs 91, 64: 78 vs
#: 117, 96: 152 vs 136.
TURN_FEW_DRONES = 64

#: Turns an ENV phase's report (UPD) may lag behind its turn and still be checked (`--verify-env`). Not measured:
#: a bound on the moves kept for it.
UPD_WINDOW = 8

#: GCS phases a scripted ground station answers ahead when its plan has nothing new for them (`Station._ahead`):
#: off a turn's critical path (one hop saved a turn: docs/performance.md, "Answers ahead"). Once it has, one more at
#: each STATUS. Measured before `PUT_GAP`: a one-drone turn on 64x64x16, 2 ahead one at a time vs 8 four at a time,
#: 5 pairs alternated: 1.16-1.53 vs 1.12-1.26 ms (median), coordinator CPU 0.7 vs 0.6 ms a turn (the four then
#: travelled together). Since the station's DONEs go out `PUT_GAP` apart, four at a time came late in a fast game
#: (its phase announced, a round trip more: 37 GCS phases heard in a 611-turn one-drone game on 64x64x16 against
#: 22 one at a time, 19 with the plan's changes alone; 48 vs 34 with 128 drones, BENCHMARKS.md "Since: the ground
#: station's answers ahead one a STATUS").
ANSWER_AHEAD = 8

#: Cells (asked, neighbours included) up to which the environment answers an ASK cell by cell in Python, not in
#: numpy over the grid (`Environment.survey`). 39 drones on 64x64x16, cell by cell vs numpy: 6 cells 12 vs 46 µs,
#: 12: 23 vs 47, 24: 45 vs 50, 48: 91 vs 64, 96: 170 vs 65.
SURVEY_FEW_CELLS = 32

#: Cells up to which a drone process's chart learns kinds, or lists the never-told neighbours of a few cells, cell
#: by cell in Python, not in numpy (`Chart.learn`, `Chart.unknown`). Cell by cell vs numpy: learn 48 cells 8 vs 17
#: µs, 96: 15 vs 25, 192: 56 vs 42; unknown 48 cells 13 vs 22 µs, 96: 26 vs 32, 192: 92 vs 87.
CHART_FEW_CELLS = 128

#: Steps around its drones within which a process flying a few drones (at most `ASK_AHEAD_MAX_DRONES`) asks ahead
#: for the never-told cells before the map comes, so that it asks again only every few turns (a swarm asks the
#: next ring each turn). Not measured: the map, usually there from the first turn, makes it moot.
ASK_AHEAD_REACH = 3
ASK_AHEAD_MAX_DRONES = 32

#: MAP queries a drone process sends (at most one a turn while none is answered) before it gives up on the map and
#: keeps asking cells. Not measured: a bound on a query nobody answers.
MAP_TRIES = 10

#: Cells per ASK sent ahead: nothing waits for these answers, so a swarm's thousands of cells go in several
#: concurrent queries and the environment never holds one huge request (or answer) at once. Not measured.
PREFETCH_CHUNK = 512

#: Drones from which a host flies them with an autopilot's swarm form (`SeedSwarm`), not one pilot per drone
#: (`--swarm-pilot-min`). In-process seed turn on 64x64x16, one pilot per drone vs the swarm form: 16 drones 527 vs
#: 612 µs, 24: 606 vs 658, 32: 699 vs 692, 48: 883 vs 776, 64: 1228 vs 975.
SWARM_MIN = 32

#: Events from one origin (a drone, a host, the coordinator...) a process may hold queued, more are refused unread
#: (network/transport.py). Not measured: far above a game's few events a turn per origin (a process hundreds of
#: turns behind resyncs from the next TURN and STATUS).
ORIGIN_QUEUE = 1024
#: Events of one origin in line at a time, the rest waiting to join it (network/transport.py `FairQueue`): a burst
#: from one origin delays another's next event by at most this many; below it, events are taken in order of
#: arrival. Not measured: above what one origin sends a process in a turn (a ground station's DONE and the two it
#: answers ahead, a host's MOVES and its presence).
ORIGIN_SHARE = 8
#: Events a process may hold queued without waking its main thread (network/transport.py `FairQueue.put`'s `quiet`:
#: a ground station's answers ahead, for turns to come, which the coordinator takes when it next wakes, before the
#: event it wakes for); beyond, they wake it as the others do. Since issue 33's budget of puts a second (`PUT_RATE`)
#: the answers ahead come one a turn, and each woke the coordinator. Measured (`dronesim bench perf`, 128 drones, five
#: rounds, issue 34): quiet, turns/s 1.09 (64x64x16) and 1.04 (256x256x32) times those with a wake for each (means;
#: BENCHMARKS.md, "Answers ahead taken without waking"). A station sends one answer ahead a STATUS: a few suffice.
QUIET_MOST = 4
#: Bytes (as payloads) of the events from one origin a process may hold queued beyond its first (which its key's
#: size limit bounds). Not measured: about 13 of the largest ASKs (525 KB, `schema.keys.size_limit`), far above a
#: host's asking ahead (512-cell ASKs of about 5 KB); a flood of big ASKs is refused unread past it.
ORIGIN_BYTES = 8 << 20

#: Puts a second a router forwards from one session on a key a drone or the ground station writes (NPS, MOVES,
#: DONE; TGT at `TGT_RATE`: its `downsampling`, schema/acl.py `flood_filters`): a process sends one a turn per key,
#: and a turn takes at least a pub/sub round trip (about 0.3 ms, BENCHMARKS.md's floor), so 10,000 never drops a real
#: one (messages closer than 0.1 ms are dropped; a scripted ground station's answers ahead, sent together, may lose all
#: but the first: it answers those phases when they are announced, entities/gcs.py `Station`), while a flood
#: reaches the coordinator at a rate its refusal of stale messages keeps up with.
PUT_RATE = 10_000.0
#: TGT puts a second a router forwards from one session on one drone's TGT key (schema/acl.py `flood_filters`: the
#: drones the access control names, or on a plain router the first `TGT_BUDGETED`): a station sends at most one TGT a
#: drone a turn (dronesim's send none: their DONE carries the targets), so a TGT for a drone within 1 ms of the last
#: one for it is dropped (a station retargeting a drone at every turn of a game above 1,000 turns a second would lose
#: some). Measured (bench flood, issue 33): a flood of stale TGTs reaches the coordinator at about one put for each
#: batch the router reads, up to 2,400 a second with `PUT_RATE` (13,367 in a game, which then ran at 0.46 of its
#: clean speed), each costing it about 55 us; this bounds them to 1,000 a second.
TGT_RATE = 1_000.0
#: Drones (D01 to D1024) whose TGT key has a budget of its own (`TGT_RATE`) on a router without access control: Zenoh's
#: `downsampling` keeps one budget a rule and a session, so one rule for every drone's TGT key would drop all but the
#: first of a station's TGTs sent together, and a plain router does not know the game's drones. Measured (a plain
#: router, one session putting 100,000 stale TGTs on D01's key, then one TGT for each of 16 other drones at once;
#: 2 cores at a load average of 8): 0, 1,024 and 4,096 such rules cost the router the same CPU (0.07-0.12 s for
#: 300,000 puts), 51-70 of the flood passed with the rules (all of them without), the 16 all passed. Drones beyond
#: have no budget on their TGT key on a plain router (under the access control each has one).
TGT_BUDGETED = 1024
#: Seconds at least between two puts a process makes on one of those keys, so that the router's budget of `PUT_RATE`
#: puts a second keeps them all: a ground station's DONEs (entities/gcs.py `Station`: its answers ahead used to go
#: out at once), a swarm host's word that it is still deciding and its MOVES (entities/drone_node.py `Effects`). 5
#: times the budget's interval (the margin: a link may still bring two together; a station sends a lost DONE again,
#: a host's MOVES lost so would leave its drones hovering a turn). Not measured: answers ahead go out over 2 ms
#: instead of at once, well before their phases; a host waits at most this long, only after a word.
PUT_GAP = 5 / PUT_RATE
#: Seconds after which a ground station sends its DONE of a phase again if that turn's STATUS has not come (then
#: twice as long each time): a DONE lost on the way (a router's budget, `PUT_GAP`) must not stall the game. At most
#: `DONE_RETRY_S`; once turns have been timed, `DONE_RETRY_TURNS` turns (the station's smoothed time between two
#: STATUS), at least `DONE_RETRY_MIN_S`. A repeat of the DONE the coordinator holds changes nothing, one that crosses
#: the turn's STATUS is refused as stale (counted). Measured (`dronesim bench perf`'s 1000-drone games, about 4.5 ms
#: a turn, 2 cores at a load average of 8-16 from other work): a loaded station's paced DONEs still reach the router
#: together at times (its link sends them in one batch) and the budget keeps the first, 2 to 6 times in 1100 turns;
#: with a fixed 1 s such a turn took 1.01 s (a fifth of a 1000-turn game, in about half the games: the ROS 2 row's
#: ratio was decided by them), with a fixed 0.1 s, 0.1 s (up to 12 % of a game); now about 20 ms.
DONE_RETRY_S = 1.0
DONE_RETRY_TURNS = 4
DONE_RETRY_MIN_S = 0.02
#: CONNECT queries a second a router forwards from one session (its `downsampling` of queries on the CONNECT key,
#: schema/acl.py `flood_filters`; a query it drops is finished at once, without a reply): a process asks once, and
#: again only once its last question is over (`CONNECT_GAP` later at least), so a flood of CONNECTs with invented
#: sessions reaches the coordinator at this rate, each of them refused cheaply, instead of all of them. Measured
#: (bench flood, issue 33): 20,000 CONNECTs reaching the coordinator cost it and the router about 0.15 ms of CPU
#: each, refused though they were (the router carries the query, its error reply and its end).
CONNECT_RATE = 100.0
#: Seconds at least between two CONNECTs from one session (network/membership.py `Membership`: its first, and each
#: asked again after an answer that did not admit it or a query the router's budget ended): twice the budget's
#: interval (two brought together by a link: the second is dropped, and asked again this much later). Not measured:
#: a process sends one or two (the RL backend: its station and its swarm host, one after the other).
CONNECT_GAP = 2 / CONNECT_RATE
#: MAP queries a second a router forwards from one session (its `downsampling` of queries on the MAP key, schema/acl.py
#: `flood_filters`; a query it drops is finished at once, without a reply): a process asks for the static map once,
#: and again (at most a turn, `MAP_TRIES` times) only if nobody answered. Each answer is the whole world (8 KB at
#: 64x64x16, 256 KB at 256x256x32). Measured (bench flood, issue 33: 20,000 MAP queries from one drone's session all
#: at once, 16 drones on 64x64x16, no budget): the environment answered 6,216 in 600 turns, its CPU a turn 4.07 ms
#: against 0.17 clean, the router's 2.58 against 1.08.
MAP_RATE = 100.0

#: Turns a second no game can exceed: a turn takes at least a pub/sub round trip (about 0.3 ms, BENCHMARKS.md's floor).
#: An entity refuses a TURN, STATUS or OVER further ahead of the turn its WELCOME named than this rate allows since
#: its CONNECT left (network/clock.py `TurnClock`): one absurd message (a STATUS at turn 2^40 from any peer on a plain
#: router) used to move its clock beyond every real message to come, and wedge it.
TURNS_PER_S_MAX = 10_000.0

#: Rejections logged in full per origin and reason in each window of `REJECT_LOG_WINDOW` seconds (schema/errors.py
#: `RejectCounter`). Not measured: a flood logs a few lines a second.
REJECT_LOG_FIRST = 3
REJECT_LOG_WINDOW = 1.0
#: Characters of a rejection's text logged (an excerpt of a payload's bytes in it, not the payload).
REJECT_EXCERPT = 200
#: Origins a process names apart in its rejection counts and logs (schema/errors.py `RejectCounter`); rejections from
#: any further origin count as "(others)". A query names its sender itself: a flood naming a new one each time
#: (CONNECTs "from" D00001...D65535) made the counts, the log and the time each rejection took grow with it.
REJECT_ORIGINS = 256

#: Bytes of the MessagePack packer's first buffer (it grows as needed): msgpack's default allocates 256 KiB for
#: every message packed, most of which are a few dozen bytes.
PACK_BUFFER = 1024

#: Observations up to which the RL environment's `Eyes.see_few` reads the drones' cells one drone at a time, not in
#: one gather. Radius 2 on 64x64x16, one by one vs one gather (CPU time, best of 7, load 5): 1 drone 5.4 vs 8.0 µs,
#: 2: 8.4 vs 10.7, 3: 7.9 vs 10.4, 4: 15.4 vs 12.5, 6: 22.9 vs 15.0, 8: 31.6 vs 17.2.
EYES_ONE_BY_ONE = 3
#: Observations up to which `Eyes.see_few`'s one gather reads each drone's whole cube (clipped: the cells beyond the
#: radius read UNKNOWN, three numpy calls); above, it gathers the sensed cells alone and places them in rows of
#: UNKNOWN (`Eyes._rows`, four calls, a quarter of the items at radius 2). Measured (callgrind instructions a step of
#: `benchmarks.rl`'s loop, safe policy, radius 2 on 64x64x16), the cube's gather vs the sensed cells': 4 drones 414.9k
#: vs 421.7k, 8: 529.5k vs 531.0k, 16: 755.7k vs 746.6k, 64: 2128.3k vs 2082.8k.
EYES_CUBE_GATHER = 8

#: Drones up to which a local RL episode keeps its rules over Python lists (`dronesim.rl_few.FewEpisode`, at most
#: 99), not in array operations (`Episode`); both play each turn through `Engine.play`. `dronesim bench rl
#: --few-gain --counts 1,16,64 --seconds 1 --repeat 3` (2026-11-29, load 9), lists vs arrays: 1 drone 2.3x-3.1x,
#: 16: 1.0x-1.9x, 64: 1.0x-1.4x (before the turn had one home, with the episode's own turn: 11 vs 97 µs a step at
#: 1 drone, 181 vs 412 at 64, 250 vs 485 at 99).
EPISODE_FEW_DRONES = 64


# ----------------------------------------------------------------------------- waits (seconds)
# How long a process waits for another before it goes on without it. None decides a game that goes well; each
# bounds what a crashed, hung or unreachable peer costs. Not measured: each is far above what it waits for (a
# round trip through a router is about 0.5 ms, a token's disappearance a few ms: BENCHMARKS.md, docs/reliability.md)
# and short enough that a person waiting does not give up.

#: The longest wait a flag or a game's configuration may give (a deadline, a grace, a pace, a lease...: checked by
#: `schema.errors.seconds` and `GameConfig`): a day. Not a tuning: a bound on input. Nobody waits a day for a turn,
#: so a longer one is a typo; and inf or 1e300 seconds overflowed the clock it is added to (a timeout beyond
#: `threading.TIMEOUT_MAX`, a time beyond time_t): an OverflowError mid-game, after every process had started.
MAX_WAIT_S = 86400.0
#: How long the drones (and the environment) have to answer a turn's phase before the missing ones hover
#: (`GameConfig.phase_deadline`, `--phase-deadline`).
PHASE_DEADLINE_S = 5.0
#: How long a drones' phase may last in all while a swarm host says it is still deciding (an empty MOVES every
#: `DECIDING_EVERY_S` while its main thread computes: the deadline counts again from each), so that a slow host that
#: is alive and working keeps its drones, and one that says so forever still ends the phase (`--phase-cap`).
PHASE_CAP_S = 60.0
#: How often a swarm host says it is still deciding a turn while its main thread computes it (an empty MOVES: the
#: coordinator waits for it, up to `PHASE_CAP_S`); a phase deadline below twice this gains nothing from it. Not
#: measured: a planning that takes this long is 100 times a D* swarm turn's usual (BENCHMARKS.md), and the words
#: are a few dozen bytes.
DECIDING_EVERY_S = 0.05
#: The share of `DECIDING_EVERY_S` the main thread's CPU time must have gone on by for a host to say it is still
#: deciding (entities/drone_node.py `Deciding`): a main thread that waits, or is blocked, says nothing (it gains a few
#: microseconds). 2 %: a process gets about 6 % of a core at load 18 on 2 cores, where a full run saw a host's 64 D*
#: drones hover at the phase deadline twice, each the turn after their targets changed (tests/test_soak.py; at 10 %
#: a host planning that slowly could not say it was still deciding: the likely cause).
DECIDING_BUSY = 0.02
#: How long a drones' phase waits, after a host's last word that it is still deciding, for its next word or its moves,
#: when that is longer than the phase deadline: a word late (a host descheduled on a loaded machine) or lost does
#: not end a phase the host is known to be working on; and as long from its start for the first word of a host that
#: said so in the last drones' phase (coordinator/engine.py `Engine.stretch`). Measured beside 6 busy loops on 2
#: cores (load 20-25 with other work): a D* swarm host's words 1.09 s apart at worst (its process got 8 ms of CPU
#: in that second), and no word yet 0.5 s into a phase; twice that.
DECIDING_SILENCE_S = 2.0
#: Seconds after which a swarm host sends again a MOVES that followed its word that it was still deciding that turn,
#: then twice as long each time while the coordinator may still wait for it (up to `DECIDING_SILENCE_S` after it:
#: entities/drone_node.py `Effects.repeat`): on a loaded machine the word and the MOVES reached the router in one
#: batch and its budget (`PUT_RATE`) dropped the MOVES (seen under 6 busy loops on 2 cores: the coordinator heard the
#: word, a subscriber on the router never saw the MOVES, and 40 drones were LOST). The coordinator takes a repeat of
#: the MOVES it holds as nothing new. Not measured: the host's link sent them 3-50 ms late there; at most 6 repeats
#: (a few hundred bytes each) for a turn whose planning outlasted `DECIDING_EVERY_S`, none for any other.
MOVES_REPEAT_S = DECIDING_EVERY_S
#: How long a game waits for every entity to connect, also when resumed (`--admit-deadline`; 0: forever).
ADMIT_DEADLINE_S = 600.0
#: The same for the game `dronesim up` plays: it starts every entity itself, on this machine, `UP_START_WINDOW` at a
#: time, so the deadline grows by `UP_ADMIT_PER_PROCESS_S` a process (400 drones, one process each: 260 s).
UP_ADMIT_DEADLINE_S = 60.0
UP_ADMIT_PER_PROCESS_S = 0.5
#: How many of its processes `dronesim up` has started at most that have not connected yet (no presence token seen)
#: and still run. Started all at once, 400 drones' sessions overran the router's pending handshakes (Zenoh's
#: `accept_pending`, 100) and timeouts on 2 cores: refused or stuck, they never connected, and the game ended ABORTED.
UP_START_WINDOW = 16
#: How long a game waits for a vanished environment to come back (`GameConfig.env_grace`).
ENV_GRACE_S = 30.0
#: How long a game holds after the coordinator's link is lost, e.g. a router restart (`--link-grace`).
LINK_GRACE_S = 30.0
#: How long a resumed game waits for its ground station once the others are back (`--gcs-grace`).
GCS_GRACE_S = 30.0
#: How long an entity waits for the coordinator to admit it (`--connect-timeout`), and for a vanished coordinator
#: to come back (`--grace`).
CONNECT_TIMEOUT_S = 30.0
COORDINATOR_GRACE_S = 30.0
#: How often a process that started the game's processes itself (the RL environment's zenoh backend) looks whether
#: one has died while it waits for them (admission, a turn's STATUS, the end): a dead one is an error at once.
PROCESS_CHECK_S = 0.25
#: How long the RL environment's zenoh backend waits for any step of its game (the game's start, a turn's STATUS,
#: the end) before it gives up (`dronesim.rl.Config.deadline`, the game's phase deadline too).
RL_WAIT_S = 30.0
#: How long a drone waits for the environment's answer to its ASK.
ASK_TIMEOUT_S = 5.0
#: How long a process waits for its own router's answer to an admin query (the endpoints it listens on).
ROUTER_ANSWER_S = 5.0
#: How long the coordinator's audit of the sessions the routers connect waits for their answers
#: (network/transport.py `audit_sessions`): a router that does not answer in time leaves the listing incomplete.
AUDIT_S = 2.0
#: How long the coordinator waits, after OVER, for entities to leave before it closes anyway (coordinator/node.py).
LINGER_S = 5.0
#: The same after a signal (OVER INTERRUPTED): a process manager stops the others too, a person wants it over. Not
#: half a second: `docker compose down --timeout 2` then stopped the entities before they had exited on OVER (143);
#: with 1 s, a coordinator stopped on a machine at load 18 was once killed (137) before it had closed.
STOP_LINGER_S = 1.0
#: How long the coordinator holds a vanished presence before it counts: when the router goes away, every token
#: vanishes, the others' sometimes just before the coordinator's own (which tells a lost link from departures).
SETTLE_S = 0.5
#: How long a starting coordinator looks for another one on its root.
PEER_CHECK_S = 2.0
#: How long a CONNECT may wait for its sender's presence token to be seen (coordinator/admission.py).
PRESENCE_WAIT_S = 5.0
#: CONNECTs that may wait for their presence token at once (coordinator/admission.py `Presences`): in all, and
#: naming one sender. More are refused at once with an error reply (the asker asks again): a flood of CONNECTs
#: with invented sessions held each one's query (about 25 KB) for PRESENCE_WAIT_S, without bound. Not measured:
#: a process sends one CONNECT at a time, and its token is seen before its CONNECT but for a race of paths.
CONNECT_WAITING = 64
CONNECT_WAITING_PER_SENDER = 4
#: How long `dronesim up`'s entities have, once the coordinator is told to stop, to see its OVER and exit.
STOP_S = 3.0
#: How long a process still running after `STOP_S` has to end on SIGTERM before it is killed.
KILL_S = 1.0
#: How long the RL zenoh backend goes on reading, once the coordinator's or the environment's presence token has
#: vanished, for the game's OVER (dronesim/rl_zenoh.py `_Game._event`): a process that ends at the game's end leaves
#: on OVER, and its token's removal (a declaration, sent at a higher priority than data) may reach this process
#: before the last STATUS and OVER do (seen once in CI: "the environment left the game" at a game's last turn). Not
#: measured: those messages are already on their way, a few ms behind; a process that left mid-game is reported
#: this much later.
LEFT_GRACE_S = 1.0
#: How long a ground station waits, after OVER, for the last turn's STATUS (sent before OVER, but on another key;
#: entities/gcs.py).
FINAL_STATUS_WAIT = 5.0
#: How long the web ground station's GCS phase waits for the STATUS of the turn before it (they travel on
#: different keys; entities/web/model.py).
STATUS_GRACE = 2.0
#: The web ground station's pace by default (`--pace`): at most one turn every this many seconds, so a person can
#: follow (the page changes it; docker/compose*.yaml's WEB_PACE the same).
WEB_PACE_S = 0.5
#: How long an HTTP thread of the web ground station waits for its main thread to carry out a command.
COMMAND_TIMEOUT = 10.0
#: Seconds between the web ground station's keep-alive comments on an event stream, so a vanished page is noticed.
KEEPALIVE = 15.0
#: How long the web ground station waits, as it closes, for its event streams to write what they hold (the end);
#: the same when it is stopped (a signal, an error, a replay served to its end), when a person wants it over.
STREAMS_CLOSE_S = 5.0
STREAMS_STOP_S = 1.0
#: The Docker image's health check (docker/healthcheck.py; $DRONESIM_HEALTH_TIMEOUT and $DRONESIM_HEALTH_STALL
#: override them): how long it waits for the router's answer (a presence token, a web page), and how long an
#: entity's progress may stand still where it should not before the container is unhealthy.
HEALTH_TIMEOUT_S = 5.0
HEALTH_STALL_S = 60.0

#: Turns a second at most that `dronesim ros2` publishes to ROS 2 (and Foxglove): each turn while the game goes no
#: faster, else the newest at this rate, so that a swarm's viewer costs a bounded share of the machine. Not
#: measured against a viewer: RViz2 and Foxglove draw at about this rate; the 1000-drone cost is in BENCHMARKS.md.
ROS_RATE = 20.0
#: The share of a core `dronesim ros2` aims to spend publishing: after a turn that took it C seconds of CPU, it
#: publishes the next no sooner than C / ROS_CPU_SHARE seconds later, but no later than `ROS_SLOWEST` after it, which
#: wins for a swarm: a 1000-drone turn costs it 13-21 ms (encoding about 1, a put per message the rest), so it is
#: published once a second and the viewer takes 1.3-1.6 % of a core, not 1 % (a small game's turn, well under a
#: millisecond, goes out at `ROS_RATE`); its ROS 2 user 0.7-1.0 %, the router 0.1-0.9 %. Measured within one game,
#: the viewer attached and detached in turn (`dronesim bench perf`'s ROS 2 row, load average 9-14: BENCHMARKS.md),
#: a 1000-drone game kept 92-101 % of its turns/s beside it. (At 5 % a 1000-drone game ran 13 % slower beside it.)
ROS_CPU_SHARE = 0.01
ROS_SLOWEST = 1.0
#: Seconds to the viewer's next turn from which it drops its STATUS subscription meanwhile (it subscribes again
#: when the turn is due, a period before it looks): a viewer publishing about once a second then hears a few STATUS
#: a second, not every one (at 1000 drones some 150 a second; the router copies each to it).
ROS_LISTEN_GAP = 0.25
#: Seconds between two trails (nav_msgs/Path) of a drone that keeps moving (the last turn's always goes out).
ROS_PATH_PERIOD = 1.0
#: Bytes at most of a ROS 2 goal (a geometry_msgs/msg/PoseStamped, 80 bytes or so with the frame "map"): a bigger
#: one is refused unread (`too-large`), as an oversized message on a game key is.
ROS_GOAL_BYTES = 4096
#: Seconds between two MAP queries of a viewer whose environment has not answered yet (it may not be up).
ROS_MAP_RETRY = 1.0

# The MAVLink ground station (entities/mavlink, docs/mavlink.md).
#: Its default turn period (s): a cell a turn then reads as 4 cells a second, a plausible speed at 1 m a cell.
MAVLINK_PERIOD = 0.25
#: How often each vehicle sends its whole telemetry (HEARTBEAT ... BATTERY_STATUS), on top of each turn's position.
MAVLINK_TELEMETRY_S = 0.5
#: How long the MAVLink reader's thread takes at most to notice it is stopped (its sockets' select timeout).
MAVLINK_STOP_S = 0.2
#: Messages read but not yet handled, at most (some 850 bytes each, decoded); more are refused (a flood cannot grow
#: the process).
MAVLINK_QUEUE = 4096
