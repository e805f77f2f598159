'use strict';
// The node-canopen suite's rig: an emulated board started by board.py (the repository's
// Python rig), its SLCAN port spoken over TCP, its control line, every received frame
// recorded, and a node-canopen Device as the master of the handwheel.

const { spawn } = require('node:child_process');
const fs = require('node:fs');
const net = require('node:net');
const path = require('node:path');
const readline = require('node:readline');
const { EventEmitter } = require('node:events');
const { Device, Eds, DataType, SdoError } = require('canopen');

const ROOT = path.resolve(__dirname, '..', '..');
const EDS = path.join(ROOT, 'eds', 'handwheel.eds');
const NODE_ID = 16;
const MASTER_ID = 1;
// The emulated board falls behind the wall clock on a loaded machine: generous, as the
// Python suite's are (tools/rig/constants.py).
const FRAME_TIMEOUT_MS = 5000;
const SDO_TIMEOUT_MS = 2000;
// The first start may build the firmware when no prepared server command is exported.
const START_TIMEOUT_MS = 900_000;

const COB = {
    NMT: 0x000,
    EMCY: 0x80 + NODE_ID,
    TPDO1: 0x180 + NODE_ID,
    TPDO2: 0x280 + NODE_ID,
    SDO_TX: 0x580 + NODE_ID,
    SDO_RX: 0x600 + NODE_ID,
    HEARTBEAT: 0x700 + NODE_ID,
};
const STATE = { BOOTUP: 0x00, STOPPED: 0x04, OPERATIONAL: 0x05, PRE_OPERATIONAL: 0x7f };

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

// SLCAN (Lawicel) text over the board's TCP port: `tIIILDD..\r` standard frames, `T` with 8
// hex digits extended, `r`/`R` remote. The board answers each frame we send with `z\r` (or
// `Z\r`) and each command with `\r`; those carry no frame and are skipped.
// Its channel is open from the start and its bus follows the node's bit rate, so neither
// `O` nor `S8` is sent (docs/EMULATED-BOARD.md).
function encodeSlcan({ id, data }) {
    const extended = id > 0x7ff;
    const head = extended
        ? 'T' + id.toString(16).toUpperCase().padStart(8, '0')
        : 't' + id.toString(16).toUpperCase().padStart(3, '0');
    return head + data.length + data.toString('hex').toUpperCase() + '\r';
}

function decodeSlcan(line) {
    const kind = line[0];
    if (!'tTrR'.includes(kind) || line.length < 2)
        return null;
    const width = kind === 't' || kind === 'r' ? 3 : 8;
    const id = parseInt(line.slice(1, 1 + width), 16);
    const length = parseInt(line[1 + width], 10);
    const remote = kind === 'r' || kind === 'R';
    const data = remote ? Buffer.alloc(0)
        : Buffer.from(line.slice(2 + width, 2 + width + 2 * length), 'hex');
    return { id, data, remote, extended: width === 8 };
}

// Records with their host time in ms (frames received or sent, decoded PDOs); tests wait
// on them instead of sleeping.
class FrameRecorder {
    constructor() {
        this.frames = [];
        this.waiters = new Set();
    }

    add(frame) {
        this.frames.push({ ...frame, t: performance.now() });
        for (const waiter of this.waiters)
            waiter.check();
    }

    mark() {
        return this.frames.length;
    }

    list(id = null, since = 0) {
        return this.frames.slice(since).filter((f) => id === null || f.id === id);
    }

    // The first frame after `since` that `match` accepts; rejects after `timeout` ms with
    // what was seen.
    waitFor(match, { since = 0, timeout = FRAME_TIMEOUT_MS, what = 'frame' } = {}) {
        return new Promise((resolve, reject) => {
            let next = since;
            const waiter = {
                check: () => {
                    for (; next < this.frames.length; ++next) {
                        if (match(this.frames[next])) {
                            finish();
                            resolve(this.frames[next]);
                            return;
                        }
                    }
                },
            };
            const timer = setTimeout(() => {
                finish();
                const seen = this.list(null, since).slice(-12).map(show).join(' ');
                reject(new Error(`${what} not received in ${timeout} ms; last: ${seen}`));
            }, timeout);
            const finish = () => {
                clearTimeout(timer);
                this.waiters.delete(waiter);
            };
            this.waiters.add(waiter);
            waiter.check();
        });
    }

    // The `n`-th frame on `id` after `since`.
    waitNth(id, n, options = {}) {
        let seen = 0;
        return this.waitFor((f) => f.id === id && ++seen === n,
            { what: `frame ${n} on ${id.toString(16)}`, ...options });
    }

    // Frames after `since` that `match` accepts, once `ms` have passed: a check that
    // something did not happen.
    async after(ms, match, since) {
        await sleep(ms);
        return this.list(null, since).filter(match);
    }

    waitId(id, data = null, options = {}) {
        const what = `${id.toString(16)}` + (data ? ` [${data.toString('hex')}]` : '');
        return this.waitFor(
            (f) => f.id === id && (data === null || f.data.equals(data)), { what, ...options });
    }
}

function show(frame) {
    return `${frame.id.toString(16).padStart(3, '0')}[${frame.data.toString('hex')}]`;
}

// Connects to 127.0.0.1:`port`, retrying while it refuses: the board listens only once it
// is up. Never a throw-away probe: the board takes the first CAN client as its master.
async function connect(port, alive, timeout) {
    const deadline = Date.now() + timeout;
    for (;;) {
        alive();
        try {
            return await new Promise((resolve, reject) => {
                const socket = net.connect(port, '127.0.0.1');
                socket.once('connect', () => resolve(socket));
                socket.once('error', reject);
            });
        } catch (error) {
            if (error.code !== 'ECONNREFUSED' || Date.now() > deadline)
                throw error;
            await sleep(50);
        }
    }
}

// The board's control line: one command a line, answered `ok` (lines before it returned)
// or `err ...`. Commands go one at a time.
class Control {
    constructor(socket) {
        this.socket = socket;
        this.lines = [];
        this.waiting = null;
        this.queue = Promise.resolve();
        readline.createInterface({ input: socket }).on('line', (line) => {
            this.lines.push(line);
            this.waiting?.();
        });
    }

    send(command) {
        const run = () => new Promise((resolve, reject) => {
            const before = [];
            this.waiting = () => {
                while (this.lines.length) {
                    const line = this.lines.shift();
                    if (line === 'ok' || line.startsWith('err')) {
                        this.waiting = null;
                        if (line === 'ok')
                            resolve(before);
                        else
                            reject(new Error(`control ${command}: ${line}`));
                        return;
                    }
                    before.push(line);
                }
            };
            this.socket.write(command + '\n');
        });
        const result = this.queue.then(run);
        this.queue = result.catch(() => {});
        return result;
    }

    // The board's counters (`status`: emulated `ms`, frames, resets, ...).
    async status() {
        const [line] = await this.send('status');
        return Object.fromEntries(line.split(' ').slice(1).map((w) => w.split('=')));
    }
}

// eds/handwheel.eds as node-canopen can read it: it knows no `$NODEID+...` defaults (it
// would read the TPDO and EMCY COB-IDs as absent), so they are resolved for node 16 first.
function handwheelEds() {
    const text = fs.readFileSync(EDS, 'latin1').replace(
        /\$NODEID\s*\+\s*(0x[0-9A-Fa-f]+|\d+)/g,
        (_, offset) => '0x' + (NODE_ID + Number(offset)).toString(16).toUpperCase());
    const file = path.join(ROOT, 'target', 'node-master', 'handwheel-node16.eds');
    fs.mkdirSync(path.dirname(file), { recursive: true });
    fs.writeFileSync(file, text);
    return Eds.fromFile(file);
}

class Rig {
    constructor(name) {
        this.name = name;
        this.folder = path.join(ROOT, 'target', 'node-master', name);
        this.frames = new FrameRecorder();
        // What the master sent, to check node-canopen's own frames.
        this.sent = new FrameRecorder();
        // TPDOs as node-canopen's RPDOs decoded them: `values` by parameter name, `data`
        // the frame's bytes.
        this.pdos = new FrameRecorder();
        // Further node-canopen devices on the same line (another master's view).
        this.listeners = [];
    }

    // Starts the board (board.py), connects the master and waits for the boot-up, which
    // is the first frame: the board starts its CPU with its CAN client.
    async open() {
        const python = process.env.NODE_MASTER_PYTHON
            || path.join(ROOT, 'target', 'interop-venv', 'bin', 'python');
        this.launcher = spawn(python, [path.join(__dirname, 'board.py'), this.folder],
            { stdio: ['pipe', 'pipe', 'inherit'] });
        this.exited = null;
        this.launcher.on('exit', (code) => { this.exited = code; });
        const [line] = await Promise.race([
            EventEmitter.once(readline.createInterface({ input: this.launcher.stdout }), 'line'),
            EventEmitter.once(this.launcher, 'exit').then(([code]) => {
                throw new Error(`board.py exited with ${code}`);
            }),
        ]);
        const ports = JSON.parse(line);
        const alive = () => {
            if (this.exited !== null)
                throw new Error(`the board stopped (${this.exited}); log: ${this.logPath}`);
        };
        this.can = await connect(ports.can_port, alive, START_TIMEOUT_MS);
        this.can.setNoDelay(true);
        let pending = '';
        this.can.on('data', (chunk) => {
            pending += chunk.toString('latin1');
            const lines = pending.split('\r');
            pending = lines.pop();
            for (const text of lines) {
                // A refused line is answered by a bell without `\r`: it may lead a frame.
                const frame = decodeSlcan(text.replace(/^\x07+/, ''));
                if (frame)
                    this.receive(frame);
            }
        });
        this.master = this.makeMaster();
        await this.frames.waitId(COB.HEARTBEAT, Buffer.from([STATE.BOOTUP]),
            { timeout: START_TIMEOUT_MS });
        this.control = new Control(await connect(ports.stim_port, alive, FRAME_TIMEOUT_MS));
        return this;
    }

    get logPath() {
        return path.join(this.folder, 'board.log');
    }

    logTail(lines = 40) {
        try {
            return fs.readFileSync(this.logPath, 'utf8').split('\n').slice(-lines).join('\n');
        } catch {
            return '(no log)';
        }
    }

    receive(frame) {
        this.frames.add(frame);
        // A decoded PDO is emitted inside receive(): this frame is the one it came from.
        this.lastFrame = frame;
        this.master?.receive(frame);
        for (const device of this.listeners)
            device.receive(frame);
    }

    send(id, data) {
        this.sent.add({ id, data });
        this.can.write(encodeSlcan({ id, data }));
    }

    // Records the PDOs `device` decodes into `this.pdos`.
    decodePdos(device) {
        device.pdo.on('pdo', (pdo) => this.pdos.add({
            id: pdo.cobId,
            data: this.lastFrame.data,
            values: Object.fromEntries(pdo.dataObjects.map((o) => [o.parameterName, o.value])),
        }));
    }

    // node-canopen's Device as the master (node 1): an SDO client for node 16, and from
    // the handwheel's EDS (mapRemoteNode) a heartbeat consumer, an EMCY consumer and RPDOs
    // that decode the device's TPDOs by the EDS mapping. Its SDO server entries are left
    // out: node-canopen reads the EDS's not-valid 0x1201 (0x80000000) as an SDO server at
    // COB-ID 0 and then fails on every SDO client lookup.
    makeMaster() {
        const master = new Device({ id: MASTER_ID });
        this.remote = handwheelEds();
        master.eds.addSdoClientParameter(NODE_ID, COB.SDO_RX, COB.SDO_TX);
        master.mapRemoteNode({ id: NODE_ID, eds: this.remote, skipSdo: true });
        master.on('message', ({ id, data }) => this.send(id, data));
        this.decodePdos(master);
        master.start();
        // The master itself Operational: its PDO module consumes only then.
        master.nmt.startNode();
        return master;
    }

    async close() {
        this.master?.stop();
        this.can?.destroy();
        this.control?.socket.destroy();
        if (this.launcher && this.exited === null) {
            const exited = EventEmitter.once(this.launcher, 'exit');
            this.launcher.stdin.end();
            await exited;
        }
    }

    // SDO through node-canopen's client ------------------------------------------------

    read(index, subIndex, dataType, options = {}) {
        return this.master.sdo.upload(
            { deviceId: NODE_ID, index, subIndex, dataType, timeout: SDO_TIMEOUT_MS, ...options });
    }

    write(index, subIndex, data, dataType, options = {}) {
        return this.master.sdo.download({
            deviceId: NODE_ID, index, subIndex, data, dataType, timeout: SDO_TIMEOUT_MS,
            ...options,
        });
    }

    // The abort code a transfer ends with (it must end with one).
    async abortCode(transfer) {
        try {
            await transfer;
        } catch (error) {
            if (error instanceof SdoError)
                return error.code;
            throw error;
        }
        throw new Error('the transfer succeeded; an abort was expected');
    }

    // NMT through node-canopen's master --------------------------------------------------

    // Sends an NMT command (node-canopen's method name) and waits for the heartbeat or
    // boot-up with `state` that must follow it at once.
    async nmt(method, state) {
        const mark = this.frames.mark();
        this.master.nmt[method](NODE_ID);
        return this.frames.waitId(COB.HEARTBEAT, Buffer.from([state]), { since: mark });
    }

    // Reset node: defaults, Pre-operational, the boot-up seen: where each test starts.
    resetNode() {
        return this.nmt('resetNode', STATE.BOOTUP);
    }

    // The selector lines set, and the firmware's debounced selection read until it shows.
    async select(axis, multiplier) {
        const code = { off: 0, x: 1, y: 2, z: 3, w: 4, v: 5 }[axis];
        await this.control.send(`axis ${axis}`);
        await this.control.send(`mult ${multiplier}`);
        const deadline = Date.now() + 3000;
        for (;;) {
            const now = [await this.read(0x2010, 1, DataType.UNSIGNED8),
                await this.read(0x2010, 2, DataType.UNSIGNED8)];
            if (now[0] === code && now[1] === multiplier)
                return;
            if (Date.now() > deadline)
                throw new Error(`selection ${now}, wanted ${[code, multiplier]}`);
            await sleep(10);
        }
    }
}

// A describe() group's board: opened before its tests, closed after them, and the last
// lines of its log printed when one of them failed.
function boardFor(name, { before, after, afterEach }) {
    const rig = new Rig(name);
    let failed = false;
    before(() => rig.open());
    afterEach((context) => {
        if (context.passed === false)
            failed = true;
    });
    after(async () => {
        if (failed)
            console.log(`--- last lines of ${rig.logPath} ---\n${rig.logTail()}`);
        await rig.close();
    });
    return rig;
}

module.exports = { COB, DataType, NODE_ID, MASTER_ID, ROOT, Rig, STATE, boardFor, sleep };
