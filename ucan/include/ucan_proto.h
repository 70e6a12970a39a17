/* ucan_proto.h - messages between the userspace SocketCAN hub and its clients.
 *
 * One AF_UNIX SOCK_SEQPACKET connection per emulated CAN_RAW socket, to
 * $UCAN_DIR/hub.sock. Both ends run on one machine (containers share the
 * directory), so messages are native-endian structs; sizes are pinned with
 * static_assert so a mismatched build fails to compile rather than misparse.
 *
 * Hub -> client messages are told apart by length alone:
 *   8 bytes          control (ucan_ctl: ACK of BIND, switch to header mode)
 *   16 / 72 bytes    "bare" frame: socket bound to one interface, no own-message
 *                    echo, so native read()/readv() of a struct can_frame works
 *   40 / 96 bytes    ucan_rxhdr + frame: sockets bound to *any*, receiving
 *                    their own messages or asking for timestamps need the source
 *                    interface, the own flag and the frame's one bus stamp
 * Client -> hub messages all start with a uint32_t type; none is longer than
 * UCAN_MSG_MAX.
 */
#ifndef UCAN_PROTO_H
#define UCAN_PROTO_H

#include <assert.h>
#include <stdint.h>
#include <linux/can.h>
#include <linux/can/raw.h>

#define UCAN_DEFAULT_DIR "/tmp/ucan"
#define UCAN_DIR_ENV "UCAN_DIR"
#define UCAN_SOCK_NAME "hub.sock"
#define UCAN_LOCK_NAME "hub.lock"
/* Abstract-namespace name every emulated socket binds to: lets the hub find a
 * connection for barriers and lets an exec'd program recognise inherited fds. */
#define UCAN_COOKIE_PREFIX "ucan/"
#define UCAN_IFINDEX_BASE 10000
#define UCAN_MAX_IFACES 64
#define UCAN_MAX_FILTERS CAN_RAW_FILTER_MAX
#define UCAN_COOKIE_MAX 64
#define UCAN_STATS_MAX_CLIENTS 1024
/* Control replies a client may leave unread beyond its full frame queue before
 * the hub closes it (a well-behaved client has one query outstanding). */
#define UCAN_CTL_RESERVE 64
/* SO_RCVBUF is honoured up to this (bench captures ask 64 MiB: candump -r) */
#define UCAN_MAX_RCVBUF (64u << 20)
/* The longest client -> hub message (a BIND with 512 filters is 4120 bytes) */
#define UCAN_MSG_MAX 8192

enum ucan_msg_type {
	UCAN_MSG_ACK = 1,	  /* hub -> client: result of BIND / query */
	UCAN_MSG_HEADER_MODE = 2, /* reserved: no longer sent (frames are told by length) */
	UCAN_MSG_BIND = 10,	  /* client -> hub: ucan_sockopts, answered by ACK */
	UCAN_MSG_SETOPT = 11,	  /* client -> hub: ucan_sockopts, made visible by BARRIER */
	UCAN_MSG_FRAME = 12,	  /* client -> hub: ucan_txhdr + frame */
	UCAN_MSG_IFLIST = 13,	  /* query -> ucan_iflist */
	UCAN_MSG_BARRIER = 14,	  /* query: drain one client's input, then ACK */
	UCAN_MSG_STATS = 15,	  /* query -> ucan_stats */
	UCAN_MSG_RESET_STATS = 16,
	UCAN_MSG_GETOPT = 17,	  /* ucan_barrier-shaped query -> ucan_sockopts of that client */
	UCAN_MSG_FRAMES = 18,	  /* client -> hub: ucan_txbatch + frames, the burst of one sendmmsg */
};

struct ucan_ctl {
	uint32_t type;
	int32_t status; /* 0 or a positive errno */
};
static_assert(sizeof(struct ucan_ctl) == 8, "control messages are told apart by length 8");

struct ucan_rxhdr {
	uint32_t ifindex;
	uint8_t flags; /* UCAN_RX_OWN */
	uint8_t pad[3];
	/* CLOCK_REALTIME when the hub took the frame from its sender (bitrate
	 * interfaces: when its transmission ended); the same for every reader */
	uint64_t stamp_sec;
	uint32_t stamp_nsec;
	uint32_t pad2;
};
#define UCAN_RX_OWN 0x01
static_assert(sizeof(struct ucan_rxhdr) == 24, "rx header size");

struct ucan_txhdr {
	uint32_t type; /* UCAN_MSG_FRAME */
	uint32_t ifindex;
};
static_assert(sizeof(struct ucan_txhdr) == 8, "tx header size");

/* Several frames in one message, so a sendmmsg's burst costs the sender one
 * message rather than one per frame (the kernel's sendmmsg is one syscall).
 * count records follow the header back to back, each a ucan_txrec and a frame
 * of rec.size bytes (CAN_MTU or CANFD_MTU), none for a bitrate= interface
 * (its frames go one per message: the hub pauses a sender between messages).
 * The hub checks the whole message before it transmits any of it, then
 * transmits the frames in order, as if they had come as count UCAN_MSG_FRAME
 * messages. */
struct ucan_txbatch {
	uint32_t type; /* UCAN_MSG_FRAMES */
	uint32_t count;
};
struct ucan_txrec {
	uint32_t ifindex;
	uint32_t size;
};
static_assert(sizeof(struct ucan_txbatch) == 8 && sizeof(struct ucan_txrec) == 8, "batch header sizes");

/* Full socket settings, sent at bind and after every change (no deltas). */
struct ucan_sockopts {
	uint32_t type;	  /* UCAN_MSG_BIND or UCAN_MSG_SETOPT */
	uint32_t ifindex; /* 0 = any */
	uint32_t err_mask;
	uint32_t rcvbuf; /* SO_RCVBUF requested by the program, bytes (0 = default) */
	uint8_t loopback, recv_own, fd_frames, join_filters;
	uint8_t bound, header_mode; /* set by the hub in GETOPT replies only */
	uint8_t timestamps;	    /* enum ucan_ts: nonzero = frames carry their stamp */
	uint8_t pad;
	uint32_t nfilters;
	struct can_filter filters[]; /* nfilters entries */
};
static_assert(sizeof(struct ucan_sockopts) == 28, "sockopts header size");

/* What the program asked for (the hub only needs to know "stamps or not"; the
 * library keeps the kind, and gets it back after exec through GETOPT). */
enum ucan_ts {
	UCAN_TS_NONE = 0,
	UCAN_TS_IOCTL = 1,	   /* SIOCGSTAMP(NS) was used: stamps kept, no control message */
	UCAN_TS_USEC = 2,	   /* SO_TIMESTAMP: SCM_TIMESTAMP, struct timeval */
	UCAN_TS_NSEC = 3,	   /* SO_TIMESTAMPNS: SCM_TIMESTAMPNS, struct timespec */
	UCAN_TS_USEC_NEW = 4, /* SO_TIMESTAMP_NEW: 64-bit fields on every ABI */
	UCAN_TS_NSEC_NEW = 5, /* SO_TIMESTAMPNS_NEW */
};
#define UCAN_TS_MAX UCAN_TS_NSEC_NEW

struct ucan_barrier {
	uint32_t type;
	char cookie[UCAN_COOKIE_MAX];
};

struct ucan_ifinfo {
	char name[16];
	uint32_t ifindex;
	uint32_t mtu;	  /* CAN_MTU or CANFD_MTU */
	uint32_t bitrate; /* bit/s, 0 = unthrottled (vcan behaviour) */
	uint32_t stuffing;
};
enum ucan_stuffing { UCAN_STUFF_WORST = 0, UCAN_STUFF_EXACT = 1, UCAN_STUFF_NONE = 2 };

struct ucan_iflist {
	uint32_t type;
	uint32_t count;
	struct ucan_ifinfo ifs[UCAN_MAX_IFACES];
};

struct ucan_ifstats {
	uint64_t frames, bytes;	   /* frames put on the bus */
	uint64_t bits;		   /* wire bits of those frames (stuffing per interface) */
	uint64_t rx_deliveries;	   /* frames handed to readers */
	uint64_t rx_drops;	   /* frames lost by slow readers */
	uint64_t tx_rejects;	   /* frames refused (size/MTU) */
	uint32_t load_permille;	   /* over the last full second, if bitrate set */
	uint32_t pad;
	uint64_t bits_per_s; /* last full second */
};

struct ucan_clientstats {
	char cookie[UCAN_COOKIE_MAX];
	int32_t pid; /* SO_PEERCRED, as seen from the hub's pid namespace */
	uint32_t ifindex;
	uint32_t bound;
	uint32_t queued;      /* frames waiting in the hub for this reader */
	uint32_t queue_limit; /* frames it may have waiting before drops */
	uint32_t pad;
	uint64_t tx_frames, rx_frames, rx_bytes, rx_drops;
};

/* What the hub refused, since it started (never reset). */
struct ucan_hubstats {
	uint64_t proto_errors;	      /* connections closed for a malformed message */
	uint64_t unread_closes;	      /* closed: left UCAN_CTL_RESERVE replies unread past a full queue */
	uint64_t refused_connections; /* accepted and closed at once: the hub was out of descriptors */
	uint64_t barriers_refused;    /* BARRIERs naming a client already being drained (nested) */
};

struct ucan_stats {
	uint32_t type;
	uint32_t nifs;
	uint32_t nclients;
	uint32_t pad;
	uint64_t uptime_ms;
	struct ucan_hubstats hub;
	struct ucan_ifinfo ifs[UCAN_MAX_IFACES];
	struct ucan_ifstats ifstats[UCAN_MAX_IFACES];
	struct ucan_clientstats clients[]; /* nclients entries */
};

#endif
