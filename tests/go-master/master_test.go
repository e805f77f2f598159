package gomaster

// gocanopen as the master of the handwheel, every test on the one board TestMain started, in
// this order (each leaves the node Pre-operational or Operational; the last one leaves it in
// its loader): the remote node built from the EDS and the device's PDO configuration, SDO,
// NMT and heartbeat, the feed records decoded into the remote node, and the library's
// segmented download that never ends past its buffer.

import (
	"encoding/binary"
	"fmt"
	"os"
	"sync"
	"testing"
	"time"

	canopen "github.com/samsamfire/gocanopen"
	"github.com/samsamfire/gocanopen/pkg/nmt"
	"github.com/samsamfire/gocanopen/pkg/pdo"
)

func TestRemoteNodeTakesTheDevicesPDOConfiguration(t *testing.T) {
	local := handwheel.GetOD()
	// The device's TPDO1 and TPDO2 became the remote node's RPDO1 and RPDO2.
	want := []struct {
		cobID    uint32
		mappings []uint32
	}{
		{tpdo1, []uint32{0x60040020, 0x20110008, 0x20300008, 0x20310010}},
		{0x280 + nodeID, []uint32{0x20320008}},
	}
	for i, w := range want {
		comm, mapping := local.Index(0x1400+i), local.Index(0x1600+i)
		cobID, err := comm.Uint32(1)
		if err != nil || cobID != w.cobID {
			t.Errorf("RPDO%d COB-ID %#x (%v), want %#x (valid)", i+1, cobID, err, w.cobID)
		}
		count, err := mapping.Uint8(0)
		if err != nil || int(count) != len(w.mappings) {
			t.Fatalf("RPDO%d has %d mappings (%v), want %d", i+1, count, err, len(w.mappings))
		}
		for sub, object := range w.mappings {
			got, err := mapping.Uint32(uint8(sub + 1))
			if err != nil || got != object {
				t.Errorf("RPDO%d mapping %d: %#x (%v), want %#x", i+1, sub+1, got, err, object)
			}
		}
	}
	// The device's TPDO1 parameters as gocanopen's configurator reads them.
	conf, err := master.Configurator(nodeID).ReadConfigurationPDO(pdo.MaxRpdoNumber + 1)
	if err != nil {
		t.Fatal(err)
	}
	if conf.CanId != tpdo1 || conf.TransmissionType != 254 || conf.InhibitTime != 20 ||
		conf.EventTimer != 100 || len(conf.Mappings) != 4 {
		t.Errorf("TPDO1 read as %+v, want 0x%x, type 254, inhibit 20, event timer 100, 4 mappings",
			conf, tpdo1)
	}
}

func TestSDOExpeditedReadsAndWrites(t *testing.T) {
	mark := frames.mark()
	period, err := handwheel.ReadUint16(0x1017, 0)
	if err != nil || period != 1000 {
		t.Fatalf("0x1017 = %d (%v), want 1000", period, err)
	}
	// Expedited: one answer, e = 1 and s = 1 with two bytes (n = 2), the value in it.
	answer, ok := frames.waitFor(mark, frameTimeout, hasID(sdoTx))
	if !ok || answer.frame.Data != [8]byte{0x4B, 0x17, 0x10, 0x00, 0xE8, 0x03, 0, 0} {
		t.Errorf("0x1017 upload answered %X, want 4B 17 10 00 E8 03 00 00", answer.frame.Data)
	}
	if err := handwheel.WriteAny(0x1017, 0, uint16(1500)); err != nil {
		t.Fatal(err)
	}
	if period, err := handwheel.ReadUint16(0x1017, 0); err != nil || period != 1500 {
		t.Errorf("0x1017 read back %d (%v), want 1500", period, err)
	}
	if err := handwheel.WriteAny(0x1017, 0, uint16(1000)); err != nil {
		t.Fatal(err)
	}
	// Identity: vendor 0, product 1, revision 1 (as the EDS says), and a serial number.
	for sub, want := range map[uint8]uint32{1: 0, 2: 1, 3: 1} {
		if got, err := handwheel.ReadUint32(0x1018, sub); err != nil || got != want {
			t.Errorf("0x1018:%d = %d (%v), want %d", sub, got, err, want)
		}
	}
	if serial, err := handwheel.ReadUint32(0x1018, 4); err != nil || serial == 0 {
		t.Errorf("0x1018:4 = %#x (%v), want the serial number from the MCU's unique ID", serial, err)
	}
}

func TestSDORefusedAccessGivesItsAbortCode(t *testing.T) {
	cases := []struct {
		what string
		err  error
		want uint32
	}{
		{"write of the read-only 0x1018:1", handwheel.WriteAny(0x1018, 1, uint32(5)), 0x06010002},
		{"write of the absent 0x1004", master.WriteRaw(nodeID, 0x1004, 0, uint32(5), false), 0x06020000},
		{"read of the write-only session key 0x2034", readAbort(0x2034, 0), 0x06010001},
		{"read of the absent 0x1018:5", readAbort(0x1018, 5), 0x06090011},
	}
	for _, c := range cases {
		if got := abortCode(c.err); got != c.want {
			t.Errorf("%s: abort %#010x (%v), want %#010x", c.what, got, c.err, c.want)
		}
	}
	if vendor, err := handwheel.ReadUint32(0x1018, 1); err != nil || vendor != 0 {
		t.Errorf("0x1018:1 = %d (%v) after the refused write, want 0", vendor, err)
	}
}

func readAbort(index uint16, sub uint8) error {
	_, err := master.ReadRaw(nodeID, index, sub, make([]byte, 8))
	return err
}

func TestSDOSegmentedUploadOfTheDeviceName(t *testing.T) {
	mark := frames.mark()
	name, err := handwheel.ReadString(0x1008, 0)
	if err != nil || name != "CNC handwheel" {
		t.Fatalf("0x1008 = %q (%v), want \"CNC handwheel\"", name, err)
	}
	// Segmented: the initiate answer gives the size (13), then 7 + 6 bytes, the last with c = 1.
	answers := frames.since(mark, hasID(sdoTx))
	want := [][8]byte{
		{0x41, 0x08, 0x10, 0x00, 13, 0, 0, 0},
		{0x00, 'C', 'N', 'C', ' ', 'h', 'a', 'n'},
		{0x13, 'd', 'w', 'h', 'e', 'e', 'l', 0},
	}
	if len(answers) != len(want) {
		t.Fatalf("%d SDO answers, want %d: %v", len(answers), len(want), answers)
	}
	for i, a := range answers {
		if a.frame.Data != want[i] {
			t.Errorf("answer %d: %X, want %X", i, a.frame.Data, want[i])
		}
	}
	// The other strings equal the EDS's defaults.
	for _, index := range []uint16{0x1009, 0x100A} {
		variable, err := handwheel.GetOD().Index(index).SubIndex(0)
		if err != nil {
			t.Fatal(err)
		}
		got, err := handwheel.ReadString(index, 0)
		if err != nil || got != string(variable.DefaultValue()) {
			t.Errorf("%#x = %q (%v), want the EDS's %q", index, got, err, variable.DefaultValue())
		}
	}
}

func TestNMTCommandsAnsweredByTheirHeartbeat(t *testing.T) {
	steps := []struct {
		target  uint8 // 0: every node
		command nmt.Command
		state   byte
	}{
		{nodeID, nmt.CommandEnterOperational, operational},
		{nodeID, nmt.CommandEnterStopped, stopped},
		{nodeID, nmt.CommandEnterPreOperational, preOperational},
		{0, nmt.CommandEnterOperational, operational},
		{0, nmt.CommandEnterStopped, stopped},
		{nodeID, nmt.CommandResetCommunication, bootUp},
		{nodeID, nmt.CommandEnterOperational, operational},
		{nodeID, nmt.CommandResetNode, bootUp},
	}
	for _, s := range steps {
		mark := frames.mark()
		sent := time.Now()
		if err := master.Command(s.target, s.command); err != nil {
			t.Fatal(err)
		}
		// A heartbeat with the new state comes at once, not a period later.
		hb, ok := frames.waitFor(mark, frameTimeout, isHeartbeat(s.state))
		if !ok || hb.at.Sub(sent) > 600*time.Millisecond {
			t.Errorf("%s to %d: heartbeat %#02x after %v (seen: %v), want it at once",
				nmt.CommandDescription[s.command], s.target, s.state, hb.at.Sub(sent), ok)
		}
	}
	// After the boot-up of reset node: Pre-operational, with the default heartbeat period.
	mark := frames.mark()
	if _, ok := frames.waitFor(mark, frameTimeout, isHeartbeat(preOperational)); !ok {
		t.Error("no Pre-operational heartbeat after reset node")
	}
	if period, err := handwheel.ReadUint16(0x1017, 0); err != nil || period != 1000 {
		t.Errorf("0x1017 = %d (%v) after reset node, want 1000", period, err)
	}
}

func TestHeartbeatFollowsTheProducerTime(t *testing.T) {
	if err := handwheel.WriteAny(0x1017, 0, uint16(100)); err != nil {
		t.Fatal(err)
	}
	defer func() {
		if err := handwheel.WriteAny(0x1017, 0, uint16(1000)); err != nil {
			t.Error(err)
		}
	}()
	// Six heartbeats at 100 ms take about 0.5 s; at the 1000 ms default they would take 5 s.
	// Loose bounds: the board's clock slips behind the wall clock on a loaded machine.
	mark := frames.mark()
	start := time.Now()
	for len(frames.since(mark, hasID(heartbeat))) < 6 {
		if time.Since(start) > 2*time.Second {
			t.Fatalf("%d heartbeats in 2 s at 0x1017 = 100", len(frames.since(mark, hasID(heartbeat))))
		}
		time.Sleep(10 * time.Millisecond)
	}
	for _, hb := range frames.since(mark, hasID(heartbeat)) {
		if hb.frame.DLC != 1 || hb.frame.Data[0] != preOperational {
			t.Errorf("heartbeat %X, want 7F", hb.frame.Data[:hb.frame.DLC])
		}
	}
}

// The feed record (TPDO1) as the device sent it.
type feedRecord struct {
	position  int32
	selection uint8 // 0x2011: axis in bits 0-2, multiplier code in bits 3-4
	status    uint8 // 0x2030: flags in bits 0-4, session in bits 5-7
	sequence  uint16
}

func decodeRecord(f canopen.Frame) feedRecord {
	return feedRecord{
		int32(binary.LittleEndian.Uint32(f.Data[0:4])), f.Data[4], f.Data[5],
		binary.LittleEndian.Uint16(f.Data[6:8]),
	}
}

// remoteCopy is the feed record as gocanopen's RPDO wrote it into the remote node's dictionary.
func remoteCopy() (feedRecord, error) {
	local := handwheel.GetOD()
	position, err1 := local.Index(0x6004).Uint32(0)
	selection, err2 := local.Index(0x2011).Uint8(0)
	status, err3 := local.Index(0x2030).Uint8(0)
	sequence, err4 := local.Index(0x2031).Uint16(0)
	for _, err := range []error{err1, err2, err3, err4} {
		if err != nil {
			return feedRecord{}, err
		}
	}
	return feedRecord{int32(position), selection, status, sequence}, nil
}

// waitForPosition waits until gocanopen's copy shows position, then until it equals the last
// record received (a record comes every 100 ms; gocanopen copies it within its 10 ms cycle).
func waitForPosition(t *testing.T, position int32) feedRecord {
	t.Helper()
	deadline := time.Now().Add(frameTimeout)
	var last feedRecord
	for time.Now().Before(deadline) {
		got, err := remoteCopy()
		if err != nil {
			t.Fatal(err)
		}
		records := frames.since(0, hasID(tpdo1))
		if len(records) > 0 {
			last = decodeRecord(records[len(records)-1].frame)
			if got.position == position && got == last {
				return got
			}
		}
		time.Sleep(5 * time.Millisecond)
	}
	t.Fatalf("the remote node's copy never showed position %d (last record received: %+v)",
		position, last)
	return feedRecord{}
}

func TestFeedRecordsDecodedIntoTheRemoteNode(t *testing.T) {
	const session, key = 5, 0xBEEF
	must(t, control.do("axis x"))
	must(t, control.do("mult 10"))
	// The firmware debounces the switch: wait until the selection shows in 0x2010.
	deadline := time.Now().Add(3 * time.Second)
	for {
		axis, err1 := handwheel.ReadUint8(0x2010, 1)
		mult, err2 := handwheel.ReadUint8(0x2010, 2)
		if err1 == nil && err2 == nil && axis == 1 && mult == 10 {
			break
		}
		if time.Now().After(deadline) {
			t.Fatalf("selection (%d, %d) (%v, %v), want X at x10", axis, mult, err1, err2)
		}
		time.Sleep(10 * time.Millisecond)
	}
	// Operational, a session opened with its key (as a CNC's master does), then the feed on.
	mark := frames.mark()
	must(t, master.Command(nodeID, nmt.CommandEnterOperational))
	if _, ok := frames.waitFor(mark, frameTimeout, isHeartbeat(operational)); !ok {
		t.Fatal("not Operational")
	}
	must(t, handwheel.WriteAny(0x2002, 0, uint8(session)))
	must(t, handwheel.WriteAny(0x2034, 0, uint16(key)))
	must(t, handwheel.WriteAny(0x2000, 0, uint8(1)))

	const enabled = 0x01
	wantSelection := uint8(1 | 1<<3) // X, multiplier code 1 (x10)
	for _, step := range []struct{ detents, position int32 }{{7, 70}, {-3, 40}} {
		must(t, control.do(fmt.Sprintf("turn %d", step.detents)))
		got := waitForPosition(t, step.position)
		if got.selection&0x1F != wantSelection || got.status != enabled|session<<5 {
			t.Errorf("after turn %d: selection %#x, status %#x; want %#x and %#x",
				step.detents, got.selection, got.status, wantSelection, enabled|session<<5)
		}
	}
	if emergencies := frames.since(mark, hasID(emcy)); len(emergencies) > 0 {
		t.Errorf("EMCY while feeding: %v", emergencies)
	}
	// The device agrees over SDO.
	if position, err := handwheel.ReadInt32(0x6004, 0); err != nil || position != 40 {
		t.Errorf("0x6004 read over SDO: %d (%v), want 40", position, err)
	}
	if ignored, err := handwheel.ReadUint32(0x2040, 1); err != nil || ignored != 0 {
		t.Errorf("ignored detents %d (%v), want 0", ignored, err)
	}
	// Leaving Operational turns the feed off.
	mark = frames.mark()
	must(t, master.Command(nodeID, nmt.CommandEnterPreOperational))
	if _, ok := frames.waitFor(mark, frameTimeout, isHeartbeat(preOperational)); !ok {
		t.Fatal("not Pre-operational")
	}
	if on, err := handwheel.ReadUint8(0x2000, 0); err != nil || on != 0 {
		t.Errorf("0x2000 = %d (%v) in Pre-operational, want 0", on, err)
	}
}

// A known bug of gocanopen (v1.4.4 and its newest sources): a segmented download of more bytes
// than the SDO client's buffer holds (1001) sends those bytes, then segments without data and
// without the last-segment bit for ever. The loader's program download (0x1F50:1) takes long
// data, so it shows the bug on the device; the board is this run's own, its flash a fresh file.
// This test fails once the library is fixed: then it should check a whole download instead.
func TestKnownBugSegmentedDownloadPastTheBufferNeverEnds(t *testing.T) {
	image := updateImage(t)
	// Into the loader: program control "stop" (Pre-operational, feed off), then "clear".
	mark := frames.mark()
	must(t, master.Command(nodeID, nmt.CommandEnterPreOperational))
	if _, ok := frames.waitFor(mark, frameTimeout, isHeartbeat(preOperational)); !ok {
		t.Fatal("not Pre-operational")
	}
	mark = frames.mark()
	must(t, handwheel.WriteAny(0x1F51, 1, uint8(0)))
	if _, ok := frames.waitFor(mark, frameTimeout, isHeartbeat(bootUp)); !ok {
		t.Fatal("no boot-up of the loader")
	}
	if kind, err := master.ReadUint32(nodeID, 0x1000, 0); err != nil || kind != 0x544F4F42 {
		t.Fatalf("0x1000 = %#x (%v), want 0x544F4F42 (\"BOOT\": the loader)", kind, err)
	}
	must(t, master.WriteRaw(nodeID, 0x1F51, 1, uint8(3), false))

	// What the client sends in its download segments (ccs 0) until it is cut off.
	var mu sync.Mutex
	var segments, dataBytes, emptySegments, lastSegments int
	var lastWithData, firstEmpty [8]byte
	cutOff := false
	bus.SetSendFilter(func(f canopen.Frame) bool {
		mu.Lock()
		defer mu.Unlock()
		if cutOff {
			return false
		}
		if f.ID == sdoRx && f.Data[0]>>5 == 0 {
			segments++
			used := 7 - int(f.Data[0]>>1&7)
			dataBytes += used
			if used > 0 {
				lastWithData = f.Data
			} else {
				if emptySegments == 0 {
					firstEmpty = f.Data
				}
				emptySegments++
			}
			if f.Data[0]&1 != 0 {
				lastSegments++
			}
		}
		return true
	})
	defer bus.SetSendFilter(nil)

	mark = frames.mark()
	done := make(chan error, 1)
	go func() { done <- master.WriteRaw(nodeID, 0x1F50, 1, image, false) }()
	// 50 empty segments, each answered by the loader, show that it goes on for ever: the
	// client sends a segment only once the last one was answered.
	deadline := time.Now().Add(15 * time.Second)
	for {
		mu.Lock()
		empty := emptySegments
		mu.Unlock()
		if empty >= 50 {
			break
		}
		select {
		case err := <-done:
			t.Fatalf("the download ended (%v): the bug is fixed? then check a whole download", err)
		default:
		}
		if time.Now().After(deadline) {
			t.Fatalf("only %d empty segments in 15 s", empty)
		}
		time.Sleep(10 * time.Millisecond)
	}
	// Cut the client off: with no answer it times out (1 s), and the transfer ends.
	mu.Lock()
	cutOff = true
	mu.Unlock()
	answers := frames.since(mark, hasID(sdoTx))
	select {
	case err := <-done:
		if abortCode(err) != 0x05040000 {
			t.Errorf("the cut-off download ended with %v, want its SDO timeout", err)
		}
	case <-time.After(10 * time.Second):
		t.Fatal("the download did not end after its answers stopped")
	}
	mu.Lock()
	defer mu.Unlock()
	if dataBytes != 1001 || lastSegments != 0 {
		t.Errorf("%d of %d bytes sent, %d last segments; want 1001 bytes, no last segment",
			dataBytes, len(image), lastSegments)
	}
	// The loader answered every segment (the one in flight at the cut-off aside), none aborted.
	acknowledged := 0
	for _, a := range answers {
		if a.frame.Data[0]&0xE0 == 0x20 {
			acknowledged++
		} else if a.frame.Data[0] == 0x80 {
			t.Errorf("the loader aborted: %X", a.frame.Data)
		}
	}
	if acknowledged < segments-1 {
		t.Errorf("%d of %d segments answered", acknowledged, segments)
	}
	t.Logf("%d of %d bytes sent in %d segments, the last with data %X, then %d empty ones "+
		"such as %X, %d answered", dataBytes, len(image), segments-emptySegments, lastWithData,
		emptySegments, firstEmpty, acknowledged)
}

// updateImage is the update file `cargo xtask fw` writes (HANDWHEEL_UPDATE_FILE, which the
// runner sets): its header passes the loader's check, so the loader takes the data that follow.
func updateImage(t *testing.T) []byte {
	path := os.Getenv("HANDWHEEL_UPDATE_FILE")
	if path == "" {
		path = "../../target/thumbv7m-none-eabi/release/handwheel-firmware.update"
	}
	image, err := os.ReadFile(path)
	if err != nil {
		t.Fatalf("the update file: %v", err)
	}
	if len(image) <= 1001 {
		t.Fatalf("the update file has %d bytes, too few to show the bug", len(image))
	}
	return image
}

func must(t *testing.T, err error) {
	t.Helper()
	if err != nil {
		t.Fatal(err)
	}
}
