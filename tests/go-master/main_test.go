package gomaster

// The suite's set-up: one board for every test (started by run_board.py, which passes its
// ports), gocanopen's network on it with the handwheel as an EDS-driven remote node, a
// recorder of the frames the tests look at, and the board's control line.

import (
	"bufio"
	"errors"
	"fmt"
	"log/slog"
	"net"
	"os"
	"strings"
	"sync"
	"testing"
	"time"

	canopen "github.com/samsamfire/gocanopen"
	"github.com/samsamfire/gocanopen/pkg/network"
	"github.com/samsamfire/gocanopen/pkg/node"
	"github.com/samsamfire/gocanopen/pkg/sdo"
)

const (
	nodeID    = 16 // the board's DIP switch is all off: the factory node-ID
	edsPath   = "../../eds/handwheel.eds"
	heartbeat = 0x700 + nodeID
	tpdo1     = 0x180 + nodeID
	sdoRx     = 0x600 + nodeID // client -> server
	sdoTx     = 0x580 + nodeID // server -> client
	emcy      = 0x080 + nodeID

	bootUp         = 0x00
	stopped        = 0x04
	operational    = 0x05
	preOperational = 0x7F

	// The board's time is emulated and may fall behind on a loaded machine: generous waits.
	frameTimeout = 5 * time.Second
)

var (
	bus       *SlcanBus
	master    *network.Network
	handwheel *node.RemoteNode
	frames    = &recorder{}
	control   *controlLine
)

func TestMain(m *testing.M) {
	os.Exit(setUpAndRun(m))
}

func setUpAndRun(m *testing.M) int {
	canPort, controlPort := os.Getenv("HANDWHEEL_CAN_PORT"), os.Getenv("HANDWHEEL_CONTROL_PORT")
	if canPort == "" || controlPort == "" {
		fmt.Fprintln(os.Stderr, "HANDWHEEL_CAN_PORT and HANDWHEEL_CONTROL_PORT are unset: "+
			"run the suite with `cargo xtask go-master` (run_board.py starts the board)")
		return 2
	}
	// gocanopen logs every NMT command and SDO abort at info level: warnings are enough here.
	slog.SetDefault(slog.New(slog.NewTextHandler(os.Stderr, &slog.HandlerOptions{Level: slog.LevelWarn})))

	bus = NewSlcanBus("127.0.0.1:" + canPort)
	nw := network.NewNetwork(bus)
	master = &nw
	// Subscribed before connecting: the boot-up comes right after the connection.
	for _, id := range []uint32{heartbeat, tpdo1, sdoTx, emcy} {
		if err := master.BusManager.Subscribe(id, 0x7FF, false, frames); err != nil {
			return fail("subscribe: %v", err)
		}
	}
	if err := master.Connect(); err != nil {
		return fail("connect: %v", err)
	}
	defer master.Disconnect()
	if _, ok := frames.waitFor(0, frameTimeout, isHeartbeat(bootUp)); !ok {
		return fail("no boot-up from node %d", nodeID)
	}
	var err error
	if control, err = dialControl("127.0.0.1:" + controlPort); err != nil {
		return fail("control line: %v", err)
	}
	// The remote node reads its dictionary from the EDS; its PDOs come from the device's own
	// configuration, read over SDO (useLocal = false).
	if handwheel, err = master.AddRemoteNode(nodeID, edsPath); err != nil {
		return fail("remote node from %s: %v", edsPath, err)
	}
	if err := handwheel.StartPDOs(false); err != nil {
		return fail("PDO configuration read from the device: %v", err)
	}
	return m.Run()
}

func fail(format string, args ...any) int {
	fmt.Fprintf(os.Stderr, "set-up failed: "+format+"\n", args...)
	return 1
}

// received is one frame and when the recorder got it.
type received struct {
	at    time.Time
	frame canopen.Frame
}

// recorder keeps every frame of the identifiers it is subscribed to, so that tests wait for
// frames instead of sleeping.
type recorder struct {
	mu     sync.Mutex
	frames []received
}

func (r *recorder) Handle(frame canopen.Frame) {
	r.mu.Lock()
	r.frames = append(r.frames, received{time.Now(), frame})
	r.mu.Unlock()
}

// mark is a position in the recording: `since` arguments look only at later frames.
func (r *recorder) mark() int {
	r.mu.Lock()
	defer r.mu.Unlock()
	return len(r.frames)
}

func (r *recorder) since(mark int, match func(canopen.Frame) bool) []received {
	r.mu.Lock()
	defer r.mu.Unlock()
	var out []received
	for _, f := range r.frames[mark:] {
		if match(f.frame) {
			out = append(out, f)
		}
	}
	return out
}

// waitFor returns the first frame after mark that matches.
func (r *recorder) waitFor(mark int, timeout time.Duration, match func(canopen.Frame) bool) (received, bool) {
	deadline := time.Now().Add(timeout)
	for {
		if found := r.since(mark, match); len(found) > 0 {
			return found[0], true
		}
		if time.Now().After(deadline) {
			return received{}, false
		}
		time.Sleep(2 * time.Millisecond)
	}
}

func isHeartbeat(state byte) func(canopen.Frame) bool {
	return func(f canopen.Frame) bool { return f.ID == heartbeat && f.DLC == 1 && f.Data[0] == state }
}

func hasID(id uint32) func(canopen.Frame) bool {
	return func(f canopen.Frame) bool { return f.ID == id }
}

// controlLine is the board's control port: one command a line, answered `ok` once applied.
type controlLine struct {
	conn   net.Conn
	reader *bufio.Reader
}

func dialControl(addr string) (*controlLine, error) {
	conn, err := net.DialTimeout("tcp", addr, frameTimeout)
	if err != nil {
		return nil, err
	}
	return &controlLine{conn, bufio.NewReader(conn)}, nil
}

func (c *controlLine) do(command string) error {
	if err := c.conn.SetDeadline(time.Now().Add(30 * time.Second)); err != nil {
		return err
	}
	if _, err := fmt.Fprintf(c.conn, "%s\n", command); err != nil {
		return err
	}
	reply, err := c.reader.ReadString('\n')
	if err != nil {
		return err
	}
	if reply = strings.TrimSpace(reply); reply != "ok" {
		return fmt.Errorf("control %q answered %q", command, reply)
	}
	return nil
}

// abortCode is the SDO abort code an error carries (0 when it carries none).
func abortCode(err error) uint32 {
	var abort sdo.Abort
	if errors.As(err, &abort) {
		return uint32(abort)
	}
	return 0
}
