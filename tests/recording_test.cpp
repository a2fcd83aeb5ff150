// Session recordings (proto/recording.h): written and read back, the token never stored, a
// file cut short or not a recording at all.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>

#include "recording.h"
#include "test_support.h"

namespace arref::wire {
namespace {

pb::ClientMessage Hello(const std::string& token) {
  pb::ClientMessage m;
  m.mutable_hello()->set_protocol_version(kProtocolVersion);
  m.mutable_hello()->set_client_name("headset");
  m.mutable_hello()->set_auth_token(token);
  return m;
}

pb::ClientMessage Seed(double x) {
  pb::ClientMessage m;
  m.mutable_seed_pose()->mutable_t_world_seed()->mutable_position()->set_x(x);
  m.mutable_seed_pose()->mutable_t_world_seed()->mutable_orientation()->set_w(1.0);
  m.mutable_seed_pose()->set_frame(pb::FRAME_CONVENTION_ROS);
  return m;
}

std::string Bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

TEST(Recording, RoundTripWithoutTheToken) {
  const testing::ScopedTempDir tmp;
  const std::string path = tmp.path() + "/s.arrec";
  pb::RecordingHeader header;
  header.set_server_version("9.9");
  header.set_session_id(7);
  header.add_robots()->set_id("kr5");
  ASSERT_OK_AND_ASSIGN(auto writer, RecordingWriter::Create(path, header));
  ASSERT_TRUE(writer->Append(0.0, Hello("s3cret-token")).ok());
  ASSERT_TRUE(writer->Append(0.25, Seed(1.5)).ok());
  writer.reset();

  EXPECT_EQ(Bytes(path).find("s3cret-token"), std::string::npos);
  ASSERT_OK_AND_ASSIGN(const Recording rec, ReadRecording(path));
  EXPECT_EQ(rec.header.format(), kRecordingFormat);
  EXPECT_EQ(rec.header.server_version(), "9.9");
  EXPECT_EQ(rec.header.session_id(), 7u);
  ASSERT_EQ(rec.messages.size(), 2u);
  EXPECT_TRUE(rec.messages[0].message().has_hello());
  EXPECT_EQ(rec.messages[0].message().hello().auth_token(), "");
  EXPECT_EQ(rec.messages[0].message().hello().client_name(), "headset");
  EXPECT_DOUBLE_EQ(rec.messages[1].t_s(), 0.25);
  EXPECT_DOUBLE_EQ(rec.messages[1].message().seed_pose().t_world_seed().position().x(), 1.5);
}

TEST(Recording, CutShortLosesOnlyTheLastMessage) {
  const testing::ScopedTempDir tmp;
  const std::string path = tmp.path() + "/s.arrec";
  ASSERT_OK_AND_ASSIGN(auto writer, RecordingWriter::Create(path, pb::RecordingHeader()));
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(writer->Append(i, Seed(i)).ok());
  writer.reset();
  std::filesystem::resize_file(path, std::filesystem::file_size(path) - 3);
  ASSERT_OK_AND_ASSIGN(const Recording rec, ReadRecording(path));
  EXPECT_EQ(rec.messages.size(), 2u);
}

TEST(Recording, OtherFilesAreRefusedByName) {
  const testing::ScopedTempDir tmp;
  const std::string path = tmp.path() + "/not.arrec";
  std::ofstream(path) << "solid ascii stl, not a recording";
  const auto rec = ReadRecording(path);
  ASSERT_FALSE(rec.ok());
  EXPECT_EQ(rec.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(rec.status().message().find(path), std::string::npos);
  EXPECT_EQ(ReadRecording(tmp.path() + "/missing.arrec").status().code(), StatusCode::kNotFound);
  EXPECT_EQ(RecordingWriter::Create(tmp.path() + "/no/dir/x.arrec", pb::RecordingHeader()).status().code(),
            StatusCode::kIoError);
}

}  // namespace
}  // namespace arref::wire
