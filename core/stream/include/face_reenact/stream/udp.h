#pragma once
// UDP sockets for the expression stream: address parsing and resolution with clear errors,
// unicast and IPv4 multicast (group join on the receiver; TTL, loopback and interface on the
// sender). RAII: a UdpSocket closes its descriptor.
#include <netinet/in.h>
#include <sys/socket.h>

#include <cstdint>
#include <span>
#include <string>

namespace face_reenact::stream {

struct UdpEndpoint {
  sockaddr_storage address{};
  socklen_t length = 0;
  std::string text;  // as the user wrote it, for messages

  bool is_ipv4_multicast() const;
  uint16_t port() const;
  std::string numeric() const;  // "1.2.3.4:5" / "[::1]:5"
};

// Parses "HOST:PORT" or "[IPV6]:PORT" and resolves HOST (getaddrinfo, numeric or DNS).
// Throws face_reenact::Error naming `what` ("--to") on a malformed value or an unresolvable host.
UdpEndpoint resolve_endpoint(const std::string& host_port, const std::string& what);

// Where a receiver listens: "PORT" (all IPv4 interfaces), "ADDR:PORT", or "GROUP:PORT" with an
// IPv4 multicast group (224.0.0.0/4).
struct ListenSpec {
  std::string address = "0.0.0.0";
  uint16_t port = 0;  // 0: any free port (tests)
  bool multicast = false;
};
ListenSpec parse_listen_spec(const std::string& text, const std::string& what);

struct MulticastSendOptions {
  int ttl = 1;                  // hops; 0 keeps datagrams on this host, 1 on the local network
  bool loopback = true;         // deliver to receivers on this host too
  std::string interface_address;  // IPv4 address of the outgoing interface; empty: routing table
};

class UdpSocket {
 public:
  UdpSocket() = default;
  explicit UdpSocket(int fd) : fd_(fd) {}
  UdpSocket(UdpSocket&& o) noexcept : fd_(o.fd_) { o.fd_ = -1; }
  UdpSocket& operator=(UdpSocket&& o) noexcept;
  UdpSocket(const UdpSocket&) = delete;
  UdpSocket& operator=(const UdpSocket&) = delete;
  ~UdpSocket();

  // A bound, non-blocking receive socket; joins the group when `spec.multicast` (on the
  // interface with IPv4 address `multicast_interface`, empty for the default one).
  // `receive_buffer_bytes` > 0 asks the kernel for that socket buffer size.
  static UdpSocket open_receiver(const ListenSpec& spec, const std::string& multicast_interface,
                                 int receive_buffer_bytes);
  // A socket connected to `to` (so ICMP errors are reported), with multicast options applied
  // when `to` is a multicast group.
  static UdpSocket open_sender(const UdpEndpoint& to, const MulticastSendOptions& multicast);

  int fd() const { return fd_; }
  uint16_t local_port() const;
  // Sends one datagram on a connected socket. Returns 0 or the errno of the failure.
  int send(std::span<const uint8_t> datagram) const;

 private:
  int fd_ = -1;
};

}  // namespace face_reenact::stream
