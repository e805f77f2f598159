'use strict';
// The CiA 302-3 program download (docs/FIRMWARE-UPDATE.md) with node-canopen as the master:
// 0x1F51 stop into the resident loader, "clear", node-canopen's segmented download of the
// update file to 0x1F50:1 with the power cut in the middle, then a second, complete download
// by node-canopen's block download, "start", and the new image answering. A board of its
// own: it rewrites the flash.

const { describe, it, before, after, afterEach } = require('node:test');
const assert = require('node:assert/strict');
const fs = require('node:fs');
const path = require('node:path');
const zlib = require('node:zlib');
const { COB, DataType, ROOT, STATE, boardFor } = require('./rig');

const { UNSIGNED8: U8, UNSIGNED32: U32, VISIBLE_STRING: TEXT } = DataType;
// What `cargo xtask fw` writes (xtask/src/fw.rs), or the file the xtask step exports.
const UPDATE_FILE = process.env.HANDWHEEL_UPDATE_FILE || path.join(
    ROOT, 'target', 'thumbv7m-none-eabi', 'release', 'handwheel-firmware.update');
const HEADER_SLOT = 512;
const BOOT = 0x544f4f42; // the loader's 0x1000
const NO_VALID_PROGRAM = 1 << 1; // 0x1F57: code 1
// Each segment is answered after the loader programmed it; a page erase takes 20 ms.
const SEGMENT_TIMEOUT_MS = 1000;

// The update file with `pad` bytes of 0xFF appended to its image and its header's length
// and CRC-32 sealed again: the same code under another CRC, so that 0x1F56 tells which of
// the two images runs.
function variant(release, pad) {
    const body = Buffer.concat([release.subarray(HEADER_SLOT), Buffer.alloc(pad, 0xff)]);
    const header = Buffer.from(release.subarray(0, HEADER_SLOT));
    header.writeUInt32LE(body.length, 0x14);
    header.writeUInt32LE(zlib.crc32(body), 0x18);
    return Buffer.concat([header, body]);
}

// The flash operations the loader takes for `image` after "clear": an erase per page the
// stream reaches (the header page was cleared already), a program per half-word that is not
// erased-blank, the first word (the validity mark) held back and programmed last.
function flashOperations(image) {
    let operations = 2; // the mark's two half-words
    for (let offset = 4; offset < image.length; offset += 2) {
        if (offset % 1024 === 0)
            operations += 1;
        if (image[offset] !== 0xff || (image[offset + 1] ?? 0xff) !== 0xff)
            operations += 1;
    }
    return operations;
}

describe('program download through the resident loader', () => {
    const rig = boardFor('update', { before, after, afterEach });

    const download = (image) => rig.write(0x1f50, 1, image, null,
        { timeout: SEGMENT_TIMEOUT_MS });
    // The tests below are one update in three steps, in order.
    let release, image, crc;
    before(() => {
        release = fs.readFileSync(UPDATE_FILE);
        image = variant(release, 100);
        crc = image.readUInt32LE(0x18);
    });

    it('0x1F51 stop: the application answers, then resets into the resident loader', async () => {
        assert.equal(release.subarray(0, 4).toString(), 'HWIM', `${UPDATE_FILE}: an update file`);
        assert.equal(await rig.read(0x1f56, 1, U32), release.readUInt32LE(0x18),
            'the release image runs');
        const mark = rig.frames.mark();
        await rig.write(0x1f51, 1, 0, U8);
        await rig.frames.waitId(COB.HEARTBEAT, Buffer.from([STATE.BOOTUP]), { since: mark });
        assert.deepEqual(await rig.control.send('mode'), ['mode loader']);
        assert.equal(await rig.read(0x1000, 0, U32), BOOT);
        assert.equal(await rig.read(0x1f56, 1, U32), release.readUInt32LE(0x18),
            'the application is still valid');
    });

    it('a power cut halfway through the download leaves a loader with no valid program',
        async () => {
            await rig.write(0x1f51, 1, 3, U8); // clear
            const half = Math.floor(flashOperations(image) / 2);
            await rig.control.send(`cut ${half} inside`);
            const mark = rig.frames.mark();
            const sent = rig.sent.mark();
            assert.equal(await rig.abortCode(download(image)), 0x05040000,
                "node-canopen's timeout: the node went dark");
            const segments = rig.sent.list(COB.SDO_RX, sent).length - 2; // initiate, abort
            assert.ok(segments > 1000 && segments < image.length / 7 - 1000,
                `cut after ${segments} segments of ${Math.ceil(image.length / 7)}`);
            // node-canopen's segmented download until the cut: each segment answered, the
            // toggle alternating.
            const answers = rig.frames.list(COB.SDO_TX, mark).map((f) => f.data[0]);
            assert.equal(answers[0], 0x60, 'initiate confirmed');
            assert.ok(answers.length > 1000, `${answers.length} answers before the cut`);
            assert.ok(answers.slice(1).every((cmd, i) => cmd === (i % 2 ? 0x30 : 0x20)),
                'segment answers with alternating toggle');
            await rig.frames.waitId(COB.HEARTBEAT, Buffer.from([STATE.BOOTUP]), { since: mark });
            assert.deepEqual(await rig.control.send('mode'), ['mode loader']);
            assert.equal(await rig.read(0x1000, 0, U32), BOOT);
            assert.equal(await rig.read(0x1f57, 1, U32), NO_VALID_PROGRAM);
            assert.equal(await rig.read(0x1f56, 1, U32), 0);
        });

    it('a second, complete download by block (node-canopen\'s, with its CRC) is taken: one '
        + 'acknowledgement per sub-block of 127 segments; "start" boots the new image', async () => {
        await rig.write(0x1f51, 1, 3, U8); // clear
        let mark = rig.frames.mark();
        await rig.write(0x1f50, 1, image, null,
            { timeout: SEGMENT_TIMEOUT_MS, blockTransfer: true });
        const answers = rig.frames.list(COB.SDO_TX, mark).map((f) => f.data);
        const segments = Math.ceil(image.length / 7);
        assert.equal(answers[0][0], 0xa4, 'block initiate confirmed, the server checks the CRC');
        assert.equal(answers[0][4], 127, 'sub-blocks of 127 segments');
        const acks = answers.slice(1, -1);
        assert.equal(acks.length, Math.ceil(segments / 127), 'one acknowledgement per sub-block');
        assert.ok(acks.every((a, i) => a[0] === 0xa2
            && a[1] === (i + 1 < acks.length ? 127 : segments - 127 * i)),
        'each acknowledges its whole sub-block');
        assert.equal(answers.at(-1)[0], 0xa1, 'end confirmed: length and CRC right');
        assert.equal(await rig.read(0x1f57, 1, U32), 0, 'no error');
        assert.equal(await rig.read(0x1f56, 1, U32), crc);

        // Start: the loader answers and resets, and the new image boots and answers.
        mark = rig.frames.mark();
        await rig.write(0x1f51, 1, 1, U8);
        await rig.frames.waitId(COB.HEARTBEAT, Buffer.from([STATE.BOOTUP]), { since: mark });
        assert.deepEqual(await rig.control.send('mode'), ['mode application']);
        assert.equal(await rig.read(0x1000, 0, U32), 0, 'the application');
        assert.equal(await rig.read(0x1f56, 1, U32), crc, 'the new image');
        assert.equal(await rig.read(0x1008, 0, TEXT), 'CNC handwheel');
        assert.equal(await rig.read(0x1f51, 1, U8), 1, 'started');
    });
});
