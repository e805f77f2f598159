// Package gomaster drives the handwheel's release image on the emulated board with gocanopen,
// a CANopen master written independently of this project (a Go port of CANopenNode's logic).
//
// gocanopen ships socketcan, kvaser and virtualcan drivers but no SLCAN one, and the emulated
// board speaks SLCAN over TCP, so SlcanBus is the small driver that joins the two: it
// implements gocanopen's canopen.Bus.
package gomaster

import (
	"bufio"
	"errors"
	"fmt"
	"net"
	"strconv"
	"strings"
	"sync"
	"syscall"
	"time"

	canopen "github.com/samsamfire/gocanopen"
)

// SlcanBus is a canopen.Bus on an SLCAN (Lawicel) line carried by TCP, such as the emulated
// board's CAN port. Only 11-bit data frames are passed on: gocanopen handles no others, and
// the handwheel sends no others.
type SlcanBus struct {
	addr     string
	conn     net.Conn
	writeMu  sync.Mutex
	filterMu sync.Mutex
	// filter sees every frame before it is sent; false holds the frame back while Send still
	// reports success (a test counts the SDO client's segments with it, then cuts them off).
	filter func(canopen.Frame) bool
	// done closes when the reader ends; nil until Subscribe starts it.
	done chan struct{}
}

func NewSlcanBus(addr string) *SlcanBus {
	return &SlcanBus{addr: addr}
}

// Connect opens the TCP connection, retrying while it is refused: the board listens only once
// it is up. No throw-away probe connection: the board takes the first client as the master and
// starts its CPU with it, so that the boot-up is the first frame the master reads. A minute
// covers a board started through cargo (`cargo xtask go-master` starts it without).
func (b *SlcanBus) Connect(...any) error {
	deadline := time.Now().Add(time.Minute)
	for {
		conn, err := net.Dial("tcp", b.addr)
		if err == nil {
			b.conn = conn
			break
		}
		if !errors.Is(err, syscall.ECONNREFUSED) || time.Now().After(deadline) {
			return fmt.Errorf("SLCAN connection to %s: %w", b.addr, err)
		}
		time.Sleep(50 * time.Millisecond)
	}
	// What a USB SLCAN adapter needs before it passes frames: 1 Mbit/s (the handwheel's
	// default), then open. The board's channel is open already and accepts both.
	return b.write("S8\rO\r")
}

// Disconnect closes the SLCAN channel and the connection.
func (b *SlcanBus) Disconnect() error {
	if b.conn == nil {
		return nil
	}
	_ = b.write("C\r")
	err := b.conn.Close()
	if b.done != nil {
		<-b.done
	}
	return err
}

// Send writes one standard data frame as `tIIIL<data>\r`.
func (b *SlcanBus) Send(frame canopen.Frame) error {
	b.filterMu.Lock()
	filter := b.filter
	b.filterMu.Unlock()
	if filter != nil && !filter(frame) {
		return nil
	}
	if frame.ID > 0x7FF || frame.DLC > 8 {
		return fmt.Errorf("SLCAN: not a standard data frame: id %#x, dlc %d", frame.ID, frame.DLC)
	}
	line := fmt.Sprintf("t%03X%d%X\r", frame.ID, frame.DLC, frame.Data[:frame.DLC])
	return b.write(line)
}

// SetSendFilter installs (or, with nil, removes) the filter Send consults.
func (b *SlcanBus) SetSendFilter(filter func(canopen.Frame) bool) {
	b.filterMu.Lock()
	b.filter = filter
	b.filterMu.Unlock()
}

func (b *SlcanBus) write(s string) error {
	b.writeMu.Lock()
	defer b.writeMu.Unlock()
	_, err := b.conn.Write([]byte(s))
	return err
}

// Subscribe starts reading: every received frame goes to listener. Reading starts only here,
// so frames that arrive before gocanopen subscribes wait in the socket instead of being lost.
func (b *SlcanBus) Subscribe(listener canopen.FrameListener) error {
	b.done = make(chan struct{})
	go func() {
		defer close(b.done)
		r := bufio.NewReader(b.conn)
		for {
			line, err := r.ReadString('\r')
			if err != nil {
				return
			}
			// A refused command is answered by a bell without a carriage return.
			line = strings.Trim(line, "\a\r\n")
			if frame, ok := parseFrame(line); ok {
				listener.Handle(frame)
			}
		}
	}()
	return nil
}

// parseFrame reads `tIIIL<data>`; other lines (the board's `z` acknowledgements and empty
// answers to commands, `\a` for a refused command, extended or remote frames) are no frames.
func parseFrame(line string) (canopen.Frame, bool) {
	if len(line) < 5 || line[0] != 't' {
		return canopen.Frame{}, false
	}
	id, err := strconv.ParseUint(line[1:4], 16, 11)
	dlc := int(line[4] - '0')
	if err != nil || dlc < 0 || dlc > 8 || len(line) != 5+2*dlc {
		return canopen.Frame{}, false
	}
	frame := canopen.NewFrame(uint32(id), 0, uint8(dlc))
	for i := 0; i < dlc; i++ {
		v, err := strconv.ParseUint(line[5+2*i:7+2*i], 16, 8)
		if err != nil {
			return canopen.Frame{}, false
		}
		frame.Data[i] = byte(v)
	}
	return frame, true
}
