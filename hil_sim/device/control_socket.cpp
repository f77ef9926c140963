#include "device/control_socket.hpp"

#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace icgt::sim {

ControlSocket::~ControlSocket() {
  if (client_ >= 0) ::close(client_);
  if (listen_ >= 0) {
    ::close(listen_);
    ::unlink(path_.c_str());
  }
}

bool ControlSocket::open(const std::string& path, std::string& error) {
  sockaddr_un a{};
  if (path.size() >= sizeof a.sun_path) {
    error = "control socket path too long: " + path;
    return false;
  }
  path_ = path;
  ::unlink(path.c_str());
  listen_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK, 0);
  a.sun_family = AF_UNIX;
  std::memcpy(a.sun_path, path.c_str(), path.size());
  if (listen_ < 0 || ::bind(listen_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || ::listen(listen_, 2) != 0) {
    error = "control socket " + path + ": " + std::strerror(errno);
    return false;
  }
  return true;
}

void ControlSocket::poll(const Handler& handler) {
  if (listen_ < 0) return;
  if (client_ < 0) {
    client_ = ::accept4(listen_, nullptr, nullptr, SOCK_NONBLOCK);
    buffer_.clear();
    if (client_ < 0) return;
  }
  char buf[256];
  const ssize_t n = ::recv(client_, buf, sizeof buf, 0);
  if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK)) {
    ::close(client_);
    client_ = -1;
    return;
  }
  if (n > 0) buffer_.append(buf, static_cast<std::size_t>(n));
  std::size_t nl;
  while ((nl = buffer_.find('\n')) != std::string::npos) {
    const std::string line = buffer_.substr(0, nl);
    buffer_.erase(0, nl + 1);
    const std::string reply = handler(line) + "\n";
    (void)::send(client_, reply.data(), reply.size(), MSG_NOSIGNAL);
  }
}

}  // namespace icgt::sim
