#pragma once
// What the security, quota and metrics tests share: a scratch directory, test certificates made
// with the openssl command (a CA, a server certificate for 127.0.0.1/localhost, client
// certificates from the CA and from a stranger CA), token files, stubs that present a token, and
// small helpers to build requests with the generated messages.

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "integration/daemon_process.hpp"
#include "integration/wire.hpp"
#include "proxima/v1/proxima.grpc.pb.h"
#include "support/random_scenes.hpp"

namespace proxima::test {

inline std::string read_text(const std::filesystem::path& path) {
    std::ifstream in(path);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
}

inline void write_text(const std::filesystem::path& path, const std::string& text) {
    std::ofstream(path) << text;
}

// A directory removed at the end of the test.
class ScratchDir {
  public:
    ScratchDir() {
        std::string pattern =
            (std::filesystem::temp_directory_path() / "proxima-hardening-XXXXXX").string();
        if (mkdtemp(pattern.data()) != nullptr) {
            m_path = pattern;
        }
    }
    ~ScratchDir() {
        std::error_code ec;
        std::filesystem::remove_all(m_path, ec);
    }
    const std::filesystem::path& path() const { return m_path; }
    std::string file(const std::string& name) const { return (m_path / name).string(); }

  private:
    std::filesystem::path m_path;
};

// Runs a shell command; true when it exits 0.
inline bool shell(const std::string& command) {
    return std::system((command + " >/dev/null 2>&1").c_str()) == 0;
}

// ca.pem/ca.key, server.pem/server.key (SAN IP:127.0.0.1, DNS:localhost, signed by ca),
// client.pem/client.key (signed by ca), stranger-ca.pem and stranger.pem/stranger.key (a client
// certificate from another CA). EC P-256 keys: quick to make.
inline bool make_certificates(const ScratchDir& dir) {
    const std::string d = dir.path().string();
    const std::string key = "-newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes";
    auto ca = [&](const std::string& name) {
        return shell("openssl req -x509 " + key + " -keyout " + d + "/" + name + ".key -out " + d +
                     "/" + name + ".pem -days 2 -subj '/CN=" + name + "'");
    };
    auto leaf = [&](const std::string& name, const std::string& ca_name, const std::string& cn,
                    const std::string& ext) {
        write_text(d + "/" + name + ".ext", ext);
        return shell("openssl req " + key + " -keyout " + d + "/" + name + ".key -out " + d + "/" +
                     name + ".csr -subj '/CN=" + cn + "'") &&
               shell("openssl x509 -req -in " + d + "/" + name + ".csr -CA " + d + "/" + ca_name +
                     ".pem -CAkey " + d + "/" + ca_name + ".key -CAcreateserial -out " + d + "/" +
                     name + ".pem -days 2 -extfile " + d + "/" + name + ".ext");
    };
    return ca("ca") && ca("stranger-ca") &&
           leaf("server", "ca", "localhost",
                "subjectAltName=IP:127.0.0.1,DNS:localhost\nextendedKeyUsage=serverAuth\n") &&
           leaf("client", "ca", "simulator-a", "extendedKeyUsage=clientAuth\n") &&
           leaf("stranger", "stranger-ca", "intruder", "extendedKeyUsage=clientAuth\n");
}

struct TlsClient {
    std::string root;  // CA the server's certificate must chain to ("" for none)
    std::string cert;  // client certificate for mutual TLS
    std::string key;
};

inline std::shared_ptr<grpc::Channel> make_tls_channel(const std::string& address,
                                                       const TlsClient& tls) {
    grpc::SslCredentialsOptions options;
    options.pem_root_certs = tls.root;
    options.pem_cert_chain = tls.cert;
    options.pem_private_key = tls.key;
    grpc::ChannelArguments args;
    args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
    return grpc::CreateCustomChannel(address, grpc::SslCredentials(options), args);
}

// A context that presents `token` (none when empty) and gives up after `ms`.
inline std::unique_ptr<grpc::ClientContext> context_for(
    const std::string& token, std::chrono::milliseconds ms = std::chrono::seconds(20)) {
    auto context = std::make_unique<grpc::ClientContext>();
    if (!token.empty()) {
        context->AddMetadata("authorization", "Bearer " + token);
    }
    deadline_in(*context, ms);
    return context;
}

// A small mesh: a unit box (12 triangles) at `x`.
inline NamedMesh box_at(double x, const std::string& name = "box") {
    NamedMesh mesh;
    mesh.name = name;
    mesh.mesh = box({x, 0, 0}, {x + 1, 1, 1});
    return mesh;
}

inline v1::CreateSceneRequest create_request(const std::string& name, int boxes) {
    v1::CreateSceneRequest request;
    request.set_name(name);
    for (int i = 0; i < boxes; ++i) {
        set_mesh(box_at(2.0 * i, "box" + std::to_string(i)), request.add_objects());
    }
    return request;
}

// CreateScene as `token`; the scene id, or "" with the status in `status`.
inline std::string create_scene(v1::Proximity::Stub& stub, const std::string& token,
                                const std::string& name, int boxes,
                                grpc::Status* status = nullptr) {
    auto context = context_for(token);
    v1::SceneInfo info;
    const auto s = stub.CreateScene(context.get(), create_request(name, boxes), &info);
    if (status != nullptr) {
        *status = s;
    }
    return s.ok() ? info.scene_id() : "";
}

// A frame on `scene` asking for separation distances (moving nothing).
inline v1::Frame separation_frame(const std::string& scene, std::uint64_t number = 1) {
    v1::Frame frame;
    frame.set_scene_id(scene);
    frame.set_frame(number);
    frame.mutable_queries()->set_separation(true);
    return frame;
}

inline grpc::Status query(v1::Proximity::Stub& stub, const std::string& token,
                          const v1::Frame& frame, v1::FrameResult* result = nullptr) {
    auto context = context_for(token);
    v1::FrameResult local;
    return stub.Query(context.get(), frame, result != nullptr ? result : &local);
}

}  // namespace proxima::test
